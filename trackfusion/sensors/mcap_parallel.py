"""Reading a long raw log in two processes: this one and one forked child (docs/read_speed.md).

The serial read (sensors/mcap_log.py) walks the file's records in order and, chunk by chunk,
inflates and checks each chunk, cuts out its messages and decodes each channel's payloads in
batches (a batch closes at the end of the chunk that brings it to ``_DECODE_BATCH`` payloads).
Here the chunks are split in two runs, cut at the chunk where both processes get about the same
work: this process reads the first run as the serial read does, while a child forked before the
walk reads the second run the same way (inflate, CRCs, record offsets, payloads, decoding in the
same batches) and hands back, per chunk, what the serial read would have added at that chunk.

**Identical to the serial read, by construction.** The child starts from the channels and
schemas of the top-level records before the first chunk, and from the number of payloads each
channel will have pending at its first chunk, predicted from the message index records of the
first run (counts per chunk and channel). When this process's walk reaches the child's first
chunk it checks both against its own state; if either differs (channels defined inside chunks,
message indexes that lie), the child's work is dropped and the second run is read here. The
batch that straddles the cut is handed back undecoded and decoded here, so every batch is the
serial read's batch, decoded by the same function. This process still walks every record of
the file (record structure, data-section CRC, metadata, footer) and takes the child's results
chunk by chunk in file order, as it reaches each chunk, so the first error and the readable
prefix of a damaged file are the serial read's: the child stops before the first chunk it cannot
take exactly (damaged, not all messages, unknown channel) and this process reads that chunk
and the rest itself, getting the serial read's error for it.

Used when fork is available (:func:`trackfusion.forked.can_fork`), the chunks hold at least
:data:`MIN_BYTES`, every message lies in a chunk, and the chunks of the second run follow each
other with only message indexes between them (what trackfusion and the mcap library write).
Otherwise the serial read runs.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from ..errors import SensorDataError
from ..forked import ForkedTasks, can_fork
from . import mcap_log as m

#: compressed chunk bytes below which a log is read in one process (forking is not worth it)
MIN_BYTES = 8 << 20
#: this process's work besides its chunks (reading and checking the child's bytes, taking its
#: results, joining the batches), as a fraction of the whole read: measured 3 % on the hour log
_PARENT_EXTRA = 0.03


@dataclass
class _Plan:
    """The child's share of a log: its chunk records (start, stop) in file order, the payloads
    pending per channel id at its first chunk (predicted), and the schemas and channels
    (id -> (topic, schema id, encoding)) it starts from."""

    chunks: list[tuple[int, int]]
    pending: dict[int, int]
    schemas: dict[int, tuple[str, str]]
    channels: dict[int, tuple[str, int, str]]


@dataclass
class _Part:
    """What the child read: per chunk it took (its first ones, in order), the message count and
    per channel (id, messages, log times or None, closed batch as (size, result) or None); per
    channel its payloads pending after them, with their decoding when they are a whole batch."""

    chunks: list[tuple[int, list[tuple[int, int, Any, Any]]]]
    pending: dict[int, tuple[list[bytes], Any]]


def _channel_table(scan: m._Scan) -> dict[int, tuple[str, int, str]]:
    return {cid: (ch.topic, ch.schema_id, ch.encoding) for cid, ch in scan.channels.items()}


def _top_level(fb: m._FileBytes, size: int) -> list[tuple[int, int, int]]:
    """(opcode, start, stop) of the complete top-level records before the data end, the footer,
    a cut record or the end of the file (record headers only; the walk checks the rest)."""
    out, pos = [], len(m.MAGIC)
    while pos + 9 <= size:
        op, length = m._RECORD_HEAD.unpack(fb[pos:pos + 9])
        stop = pos + 9 + length
        if stop > size or op in (m._DATA_END, m._FOOTER):
            break
        out.append((op, pos, stop))
        pos = stop
    return out


def _start_table(scan: m._Scan, fb: m._FileBytes, records: list[tuple[int, int, int]]) -> m._Scan | None:
    """A scan holding the schemas and channels of the top-level records before the first chunk
    (None when one does not parse)."""
    table = m._Scan(scan.path, scan.wanted)
    table.decoder.parallel = False
    for op, start, stop in records:
        if op == m._CHUNK:
            break
        if op in (m._SCHEMA, m._CHANNEL):
            try:
                m._read_record(table, op, fb[start + 9:stop], start)
            except m._Corrupt:
                return None
    return table


def _counts(fb: m._FileBytes, records: list[tuple[int, int, int]]) -> list[dict[int, int] | None]:
    """Per chunk record, its messages per channel id from the message index records after it
    (None when it has none or one is malformed)."""
    counts: list[dict[int, int]] = []
    malformed: set[int] = set()
    for op, start, stop in records:
        if op == m._CHUNK:
            counts.append({})
        elif op == m._MESSAGE_INDEX and counts:
            head = fb[start + 9:start + 15]
            cid, length = struct.unpack("<HI", head) if len(head) == 6 else (0, -1)
            if length < 0 or length % 16 or 6 + length != stop - start - 9:
                malformed.add(len(counts) - 1)
            else:
                counts[-1][cid] = counts[-1].get(cid, 0) + length // 16
    return [None if i in malformed or not c else c for i, c in enumerate(counts)]


def _pending(table: m._Scan, counts: list[dict[int, int]]) -> dict[int, int]:
    """Payloads pending per channel id after chunks with these message counts (the serial read's
    batching: a channel decodes its pending payloads at the end of the chunk that brings them
    to ``_DECODE_BATCH``; channels it does not decode keep none)."""
    out = {}
    for cid, ch in table.channels.items():
        if table.wanted is not None and ch.topic not in table.wanted:
            out[cid] = 0
            continue
        try:
            m._channel_schema(table, ch)
            closes = True
        except m._Bad:
            closes = False
        p = 0
        for chunk in counts:
            p += chunk.get(cid, 0)
            if closes and p >= m._DECODE_BATCH:
                p = 0
        out[cid] = p
    return out


def _plan(scan: m._Scan, fb: m._FileBytes, size: int) -> tuple[_Plan, m._Scan] | None:
    """The child's share, or None when the log is read in one process (module docstring)."""
    if fb[0:len(m.MAGIC)] != m.MAGIC:
        return None
    records = _top_level(fb, size)
    if any(op == m._MESSAGE for op, _, _ in records):
        return None
    chunks = [(start, stop) for op, start, stop in records if op == m._CHUNK]
    total = sum(stop - start for start, stop in chunks)
    if len(chunks) < 2 or total < MIN_BYTES:
        return None
    first = len(chunks)  # the child's run: chunks with only message indexes between them, to the last
    ops = [op for op, _, _ in records]
    last = max(i for i, op in enumerate(ops) if op == m._CHUNK)
    i = last
    while i >= 0 and ops[i] in (m._CHUNK, m._MESSAGE_INDEX):
        first -= ops[i] == m._CHUNK
        i -= 1
    table = _start_table(scan, fb, records)
    if table is None:
        return None
    counts = _counts(fb, records)
    known = next((i for i, c in enumerate(counts) if c is None), len(chunks))  # counts known before it
    messages = sum(sum(c.values()) for c in counts if c is not None) or 1
    best, done = None, 0
    for k in range(1, min(known, len(chunks) - 1) + 1):
        done += chunks[k - 1][1] - chunks[k - 1][0]
        if k < first:
            continue
        pending = _pending(table, counts[:k])
        here = done + (sum(pending.values()) / messages + _PARENT_EXTRA) * total  # (the straddling batches too)
        cost = max(here, total - done)
        if best is None or cost < best[0]:
            best = (cost, k, pending)
    if best is None:
        return None
    _, k, pending = best
    return _Plan(chunks[k:], pending, dict(table.schemas), _channel_table(table)), table


def _read_part(table: m._Scan, plan: _Plan, fb: m._FileBytes) -> _Part:
    """The child: read the plan's chunks into ``table`` as the serial read would, from the
    planned pending counts; stops before the first chunk it cannot take exactly."""
    for cid, ch in table.channels.items():
        ch.held = plan.pending[cid]
    taken = []
    for start, stop in plan.chunks:
        try:
            records = m._chunk_data(fb[start + 9:stop], start, complete=True)
            offsets = m._message_offsets(records)
        except Exception:  # noqa: BLE001 (a damaged chunk: read by the parent, giving the serial error)
            break
        if offsets is None:
            break
        before = {cid: (ch.count, len(ch.times), len(ch.batches), ch.decoded) for cid, ch in table.channels.items()}
        try:
            table.add_messages(records, offsets, start)  # (raises before changing anything)
        except m._Corrupt:
            break
        per_channel = []
        for cid, ch in table.channels.items():
            count, times, batches, decoded = before[cid]
            if ch.count == count:
                continue
            per_channel.append((cid, ch.count - count, ch.times[times] if len(ch.times) > times else None,
                                (ch.decoded - decoded, ch.batches[batches][1]) if len(ch.batches) > batches else None))
            ch.times, ch.batches = [], []
        taken.append((len(offsets), per_channel))
    pending = {}
    for cid, ch in table.channels.items():
        if ch.payloads:
            decoded = None
            if not ch.held:  # a whole batch: decoded as the serial read decodes its last one
                try:
                    decoded = m._decode_batch(ch.payloads, m._channel_schema(table, ch))
                except m._Bad:
                    pass
            pending[cid] = (ch.payloads, decoded)
    return _Part(taken, pending)


class _Split:
    """This process's side of a two-process read: takes the child's chunks as the walk reaches them."""

    def __init__(self, plan: _Plan, tasks: ForkedTasks, task):
        self.plan, self.tasks, self.task = plan, tasks, task
        self.index = {start: i for i, (start, _) in enumerate(plan.chunks)}
        self.part: _Part | None = None
        self.usable = True
        self.next = 0

    def take(self, scan: m._Scan, at: int) -> bool:
        """Add the child's reading of the complete chunk record at ``at`` to ``scan``; False when
        this process must read it (not the child's, or the child did not take it)."""
        i = self.index.get(at)
        if i is None or not self.usable:
            return False
        if i != self.next:
            raise SensorDataError(f"{scan.path}: changed while being read")
        self.next += 1
        if self.part is None:
            self.part = self._collect(scan)
            if self.part is None:
                self.usable = False
                return False
        if i >= len(self.part.chunks):
            return False
        n_messages, per_channel = self.part.chunks[i]
        self.part.chunks[i] = None
        for cid, count, times, batch in per_channel:
            ch = scan.channels[cid]
            ch.count += count
            if times is not None:
                ch.times.append(times)
            if batch is not None:
                size, result = batch
                if isinstance(result, m._Held):  # the batch that straddles the cut: decoded here
                    ch.payloads.extend(result.payloads)
                    ch.decode_pending(m._channel_schema(scan, ch), scan.decoder)
                else:
                    ch.batches.append((ch.decoded, result))
                    ch.decoded += size
        scan.n_messages += n_messages
        if i == len(self.part.chunks) - 1:
            for cid, (payloads, decoded) in self.part.pending.items():
                ch = scan.channels[cid]
                ch.payloads.extend(payloads)
                if decoded is not None:
                    ch.tail = (len(ch.payloads), decoded)
            self.part.pending = {}
        return True

    def _collect(self, scan: m._Scan) -> _Part | None:
        """The child's part when this process's state at the child's first chunk is the one it
        started from; None (read the rest here) otherwise, or when the child died or failed."""
        try:
            part = self.task.result()
        except Exception:  # noqa: BLE001 (the child died or failed: no part, as without a child)
            return None
        if scan.schemas != self.plan.schemas or _channel_table(scan) != self.plan.channels:
            return None
        if any(len(ch.payloads) != self.plan.pending[cid] for cid, ch in scan.channels.items()):
            return None
        return part

    def close(self) -> None:
        """Stop the child if it still runs (the walk ended before its chunks, or failed)."""
        self.tasks.kill()


def start_split(scan: m._Scan, fb: m._FileBytes, size: int) -> _Split | None:
    """Fork the child reading the second run of chunks of the file (``fb``, ``size`` bytes) and
    return this process's side, or None to read the whole file here (module docstring)."""
    if not can_fork():
        return None
    try:
        planned = _plan(scan, fb, size)
    except Exception:  # noqa: BLE001 (a damaged file: the walk finds what is wrong, in file order)
        planned = None
    if planned is None:
        return None
    plan, table = planned
    scan.decoder.parallel = False  # both CPUs are busy reading: no decode workers
    tasks = ForkedTasks()
    task = tasks.submit("reading the second half of the log", _read_part, table, plan, fb)
    return _Split(plan, tasks, task)

"""``smoother.chunk_s: auto`` (the default, fusion/settings.py ``SmootherSettings.one_batch_up_to_s``):
a run of up to 2 h is one batch where its keyframes allow (the memory grows with them), a longer
one goes in chunks of an hour; a written ``chunk_s`` keeps its meaning."""

from __future__ import annotations

import pytest

from trackfusion.fusion.settings import (AUTO_CHUNK_S, AUTO_ONE_BATCH_KEYFRAMES, CHUNK_OVERLAP_S,
                                         SmootherSettings)


@pytest.mark.parametrize("spacing_s, up_to_s", [(0.05, 4200.0), (0.1, 4200.0), (0.15, 6300.0), (0.2, 7200.0),
                                                (1.0, 7200.0)])
def test_auto_one_batch_from_the_keyframe_spacing(spacing_s, up_to_s):
    """0.1 s keyframes and closer keep the hour and its overlap they had; 0.2 s ones (the wheel
    path's) make a 2 h survey one batch; the one batch never holds more keyframes than an hour and
    600 s of 0.1 s ones unless a chunk of the hour does."""
    sm = SmootherSettings()
    assert sm.chunk_s == "auto" and sm.chunk_length_s == AUTO_CHUNK_S and sm.chunk_overlap_s == CHUNK_OVERLAP_S
    limit_s = sm.one_batch_up_to_s(spacing_s)
    assert limit_s == pytest.approx(up_to_s)
    assert limit_s / spacing_s <= AUTO_ONE_BATCH_KEYFRAMES + 1e-6 or limit_s == AUTO_CHUNK_S + CHUNK_OVERLAP_S


@pytest.mark.parametrize("written, up_to_s", [({"chunk_s": 1200.0}, 1800.0), ({"chunk_s": None}, None),
                                              ({"chunk_s": 9000.0, "overlap_s": 300.0}, 9300.0),
                                              ({"overlap_s": 1200.0}, 7200.0)])
def test_a_written_chunk_keeps_its_meaning(written, up_to_s):
    """A number: runs longer than the chunk and its overlap are chunked, whatever the keyframes; null:
    none; ``auto`` with a written overlap: the hour's chunk with that overlap."""
    sm = SmootherSettings(**written)
    assert sm.one_batch_up_to_s(0.2) == up_to_s
    if written.get("chunk_s", "auto") is not None:
        assert sm.one_batch_up_to_s(0.1) == (up_to_s if "chunk_s" in written else 4800.0)


@pytest.mark.parametrize("written", [{"chunk_s": 30}, {"chunk_s": "long"}, {"chunk_s": True},
                                     {"chunk_s": float("inf")}, {"overlap_s": 3600.0}])
def test_bad_chunks_are_refused(written):
    with pytest.raises(ValueError):
        SmootherSettings(**written)


@pytest.mark.parametrize("spacing_s, duration_s, chunked", [(0.2, 7100.0, False), (0.2, 7300.0, True),
                                                            (0.1, 4100.0, False), (0.1, 4300.0, True)])
def test_the_run_decides_by_its_keyframes(tmp_path, spacing_s, duration_s, chunked):
    """The pipeline's decision (``pipeline._in_chunks``) takes the keyframe spacing it was given; a
    total-station run too long for one batch is refused in one line naming the key."""
    from types import SimpleNamespace

    from trackfusion.errors import ConfigError
    from trackfusion.pipeline import _in_chunks, parse_pipeline
    data = {"name": "t", "inputs": {"log": "log.mcap"}, "keyframes": {"spacing_s": spacing_s},
            "trolley": {"wheelbase_m": 1.2, "lever_arm_imu_v_m": [0.0, -0.7, 0.25]},
            "sensors": {"imu": {"grade": "navigation"}}, "factors": {"gnss": False}}
    (tmp_path / "log.mcap").write_bytes(b"")
    pipeline = parse_pipeline(data, "p.yaml", tmp_path)
    assert _in_chunks(pipeline, SimpleNamespace(prisms=None), duration_s) is chunked
    if chunked:
        with pytest.raises(ConfigError, match="smoother.chunk_s: total-station runs"):
            _in_chunks(pipeline, SimpleNamespace(prisms=object()), duration_s)
    else:
        assert _in_chunks(pipeline, SimpleNamespace(prisms=object()), duration_s) is False

"""``python -m trackfusion``: the ``trackfusion`` command (:func:`trackfusion.cli.entry`)."""

from .cli import entry

if __name__ == "__main__":
    entry()

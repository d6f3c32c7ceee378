"""The `babblegen` console script. For `generate` it takes SIGINT and SIGTERM over at its first line, before the
half second of imports `babblegen.cli` needs: a signal meanwhile is recorded and the run stops as soon as it
starts, with exit status 130, instead of the default actions (SIGTERM ending the process at once, SIGINT a
KeyboardInterrupt in the middle of an import). Only the interpreter's own start-up, the first tens of milliseconds
of the process, comes before that line: a signal then gets the default action, before anything is written."""

from __future__ import annotations

import sys

from babblegen.interrupts import Interrupts


def entry_point() -> None:
    if sys.argv[1:2] == ["generate"]:
        Interrupts(raising=False).install()  # until the process ends (`babblegen.cli.entry_point`)
    from babblegen.cli import entry_point as run  # heavy (numpy, the explorers): after the handlers are in place

    run()

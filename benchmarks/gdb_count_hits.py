"""Runs inside gdb (``gdb -batch -x gdb_count_hits.py --args PROGRAM ...``) for count_vendor_instructions.py: counts
how many times each listed instruction of the listed shared libraries executes while PROGRAM runs.

The spec (a JSON file named by BABBLEGEN_COUNT_SPEC) lists sites as (library path, file offset). Each time the
program loads a library (``catch load``), the sites of every library newly mapped get a breakpoint at the mapping's
address plus the offset; a breakpoint counts and never stops. gdb reads no symbols (``auto-solib-add off``), so the
program starts as fast as under gdb it can. The counts, the addresses and the exit status go to the spec's ``out``.
"""

import json
import os

import gdb  # noqa: F401 (gdb's own module: this file runs in gdb's Python)

with open(os.environ["BABBLEGEN_COUNT_SPEC"]) as spec:
    SPEC = json.load(spec)
SITES = SPEC["sites"]  # [{"library": realpath, "file_offset": int}, ...]
COUNTS = [0] * len(SITES)
ADDRESSES: list = [None] * len(SITES)


class Counter(gdb.Breakpoint):
    def __init__(self, index: int, address: int):
        super().__init__(f"*{address:#x}", internal=True)
        self.index = index

    def stop(self) -> bool:
        COUNTS[self.index] += 1
        return False


def mappings(pid: int) -> list[tuple[int, int, int, str, str]]:
    """(start, end, file offset, permissions, path) of every file-backed mapping of the process."""
    out = []
    with open(f"/proc/{pid}/maps") as maps:
        for line in maps:
            parts = line.split(maxsplit=5)
            if len(parts) < 6 or not parts[5].startswith("/"):
                continue
            start, end = (int(x, 16) for x in parts[0].split("-"))
            out.append((start, end, int(parts[2], 16), parts[1], parts[5].strip()))
    return out


def place_breakpoints(pid: int) -> None:
    """A counting breakpoint on each site whose library is mapped now and has none yet."""
    maps = mappings(pid)
    for i, site in enumerate(SITES):
        if ADDRESSES[i] is not None:
            continue
        for start, end, offset, perms, path in maps:
            if path == site["library"] and "x" in perms and offset <= site["file_offset"] < offset + end - start:
                ADDRESSES[i] = start + site["file_offset"] - offset
                Counter(i, ADDRESSES[i])
                break


for command in (
    "set pagination off",
    "set confirm off",
    "set auto-solib-add off",
    "set print thread-events off",
    "set print inferior-events off",
    "handle SIGCHLD SIGPIPE SIGALRM SIGUSR1 SIGUSR2 SIGWINCH SIGPROF SIGINT SIGTERM nostop noprint pass",
    "catch load",
):
    gdb.execute(command, to_string=True)

exit_status = None
gdb.execute("run", to_string=False)
while True:
    inferior = gdb.selected_inferior()
    if not inferior.is_valid() or inferior.pid == 0:
        code = gdb.convenience_variable("_exitcode")
        exit_status = int(code) if code is not None else -1
        break
    place_breakpoints(inferior.pid)
    stop = gdb.execute("info program", to_string=True)
    if "signal" in stop.lower() and "SIGTRAP" not in stop:
        print(f"count: the program stopped on a signal: {stop.strip()}")
        gdb.execute("kill")
        exit_status = -2
        break
    gdb.execute("continue", to_string=False)

with open(SPEC["out"], "w") as out:
    json.dump({"counts": COUNTS, "addresses": ADDRESSES, "exit_status": exit_status}, out)

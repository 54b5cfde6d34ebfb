"""Run one command and report its wall time and its own peak RSS as JSON (figures 1, 6, 7).

    python bench/child.py REPORT.json -- command args...

Why a wrapper: a child forked from the benchmark process starts as a copy of it, and Linux
counts that copy's resident set in the child's ``ru_maxrss`` (it is recorded at exec). Forked
from this small process instead, the peak is the command's own. ``os.wait4`` returns the usage
of exactly that child, so nothing else it or the benchmark ran is mixed in.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time


def main() -> int:
    report, separator, *command = sys.argv[1:]
    if separator != "--" or not command:
        print(__doc__, file=sys.stderr)
        return 2
    start = time.perf_counter()
    child = subprocess.Popen(command)
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - start
    child.returncode = code = os.waitstatus_to_exitcode(status)
    rss_unit = 1 if sys.platform == "darwin" else 1024  # ru_maxrss: bytes on macOS, KiB on Linux
    with open(report, "w") as out:
        json.dump(
            {"seconds": seconds, "max_rss_bytes": usage.ru_maxrss * rss_unit, "returncode": code},
            out,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

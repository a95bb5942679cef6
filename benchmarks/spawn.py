"""Run one command and write its wall time and resource usage as JSON (used by the harness).

    python -I -S benchmarks/spawn.py RESULT.json COMMAND [ARG ...]

Why a separate launcher: on Linux a child's ``ru_maxrss`` keeps the high-water mark of the memory
it had at ``fork``, i.e. a copy of its parent, across ``exec``. Forked straight from the harness
(which holds numpy, gtsam and generated graphs, ~150 MB) every process would report at least that
much. This launcher is a bare interpreter (``-S``: no site packages, ~10 MB), so the command it
forks starts from ~10 MB and ``ru_maxrss`` is the command's own peak. The wall time is measured
here, from just before ``fork`` to the reaping ``wait4``, so the launcher's start-up is not in it.
"""

import json
import os
import sys
import time

result_path, command = sys.argv[1], sys.argv[2:]
start = time.perf_counter()
pid = os.fork()
if pid == 0:  # the command; the launcher's stdin/stdout/stderr are inherited
    try:
        os.execvp(command[0], command)
    finally:
        os._exit(127)
_, status, usage = os.wait4(pid, 0)
wall = time.perf_counter() - start
with open(result_path, "w") as stream:
    json.dump(
        {
            "wall": wall,
            "returncode": os.waitstatus_to_exitcode(status),
            "max_rss": usage.ru_maxrss * 1024,  # Linux reports KiB
            "cpu": usage.ru_utime + usage.ru_stime,
        },
        stream,
    )

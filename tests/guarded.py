"""Run code that might read an endless file (/dev/zero) or block on a FIFO in a child process with
a memory cap and a deadline, so that a loader doing so fails the test instead of exhausting the
machine's memory or hanging it."""

import os
import subprocess
import sys

import pytest

# torch (a CUDA build maps gigabytes of address space at import) is imported first; the cap is then
# 3 GiB of address space beyond what the process holds.
_PRELUDE = """import resource, torch
vm = next(int(line.split()[1]) << 10 for line in open("/proc/self/status") if line.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (vm + (3 << 30), vm + (3 << 30)))
"""


def run_guarded(code: str, timeout: float = 60.0) -> str:
    """stdout and stderr of Python `code` run in a child process with 3 GiB more address space; the
    test fails if the child runs longer than `timeout` s. The child's thread pools take one thread:
    OpenBLAS reserves buffers per thread, which on a many-core machine alone exceed the cap."""
    one = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    try:
        done = subprocess.run(
            [sys.executable, "-c", _PRELUDE + code],
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
            env={**os.environ, **one},
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout} s (blocked on a FIFO?):\n{code}")
    return done.stdout + done.stderr

"""Run code that might read an endless file (/dev/zero) or block on a FIFO in a child process with
a memory cap and a deadline, so that a loader doing so fails the test instead of exhausting the
machine's memory or hanging it."""
import subprocess
import sys

import pytest

_PRELUDE = "import resource\nresource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))\n"


def run_guarded(code: str, timeout: float = 60.0) -> str:
    """stdout and stderr of Python `code` run in a child process with 3 GiB of address space; the
    test fails if the child runs longer than `timeout` s."""
    try:
        done = subprocess.run([sys.executable, "-c", _PRELUDE + code], capture_output=True, text=True,
                              timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout} s (blocked on a FIFO?):\n{code}")
    return done.stdout + done.stderr

"""`python -m bench`: the benchmark suite (bench.run)."""

from .run import main

main()

"""``python -m benchmarks``: the speed/accuracy suite (``benchmarks/suite.py``); ``--help`` lists the other scripts."""

from .suite import main

main()

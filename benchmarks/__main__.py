"""``python -m benchmarks``: list the benchmark scripts."""

print("benchmarks: python -m benchmarks.merl_accuracy [--quick]   accuracy on the MERL split\n"
      "            python -m benchmarks.speed [--quick]           speed beside the scipy peer")

"""``python -m benchmarks``: list the benchmark scripts."""

print("benchmarks: python -m benchmarks.merl_accuracy [--quick]   accuracy on the MERL split\n"
      "            python -m benchmarks.speed [--quick]           speed beside the scipy peer\n"
      "            python -m benchmarks.model_selection [--quick] automatic model choice: confusion, error, cost")

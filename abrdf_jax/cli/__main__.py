"""``python -m abrdf_jax.cli``: the ``abrdf-jax`` command."""

import sys

from . import main

sys.exit(main())

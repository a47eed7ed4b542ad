"""``python -m gen_independent OUT_DIR --n N`` (from tests/analysis): generate the study plan's runs."""

import sys

from .plan import main

sys.exit(main())

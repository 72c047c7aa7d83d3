"""`python -m benchmarks TARGET [flags]`: the one runner of the developers' benchmarks."""

import sys

from benchmarks.cli import main

sys.exit(main())

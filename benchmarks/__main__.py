"""`python -m benchmarks [--quick] [--only SECTION ...]`."""

from .run import main

raise SystemExit(main())

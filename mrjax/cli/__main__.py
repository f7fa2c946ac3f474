"""`python -m mrjax.cli`: the `mrjax` command."""

import sys

from ._main import main

sys.exit(main())

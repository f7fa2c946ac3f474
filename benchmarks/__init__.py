"""mrjax benchmark suite (not tests: nothing here is collected by pytest).

Run everything with `python -m benchmarks` (or `python -m benchmarks --quick` for a reduced
sweep). Results go to `benchmarks/results.md`, `benchmarks/results.json` and PNG figures beside
them. See `benchmarks/run.py` for what is measured and how.
"""

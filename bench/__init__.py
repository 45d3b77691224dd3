"""Benchmarks of undertow: `python -m bench NAME [options]`, `python -m bench list`."""

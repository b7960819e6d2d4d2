"""imudiag benchmarks: ``python -m benchmarks`` (benchmarks/run.py) and the scripts it uses."""

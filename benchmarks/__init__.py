"""The benchmarks behind BENCHMARKS.md, and the code only they use (multi-view triangulation, the Qualisys
calibration reader), kept out of the runtime package. The scripts run from this folder (`python
benchmarks/bench_x.py`) and import their siblings by name; tests import them as `benchmarks.<module>`."""

"""How long the detection cache's content key takes: streamed SHA-256 and BLAKE2b of a video file's bytes, against
the time the detector needs for the same file (the key is computed on every run, cached or not).

    python benchmarks/bench_cache_hash.py [VIDEO] [--size-mib 1024]

Without VIDEO, a file of --size-mib random bytes is hashed (the throughput does not depend on the content)."""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import tempfile
import time
from pathlib import Path


def throughput(path: Path, algorithm: str, repeats: int = 3) -> float:
    """Median MiB/s of hashing `path` with `algorithm`, streamed in 1 MiB blocks."""
    size = path.stat().st_size / 2**20
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        with open(path, "rb") as f:
            hashlib.file_digest(f, algorithm)
        times.append(time.perf_counter() - started)
    return size / statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video", nargs="?", type=Path)
    parser.add_argument("--size-mib", type=int, default=1024)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.video
        if path is None:
            path = Path(tmp) / "random.bin"
            with open(path, "wb") as f:
                for _ in range(args.size_mib):
                    f.write(os.urandom(2**20))
        size = path.stat().st_size / 2**20
        for algorithm in ("sha256", "blake2b"):
            rate = throughput(path, algorithm)
            print(f"{algorithm}: {rate:.0f} MiB/s, {size / rate:.2f} s for {size:.0f} MiB")


if __name__ == "__main__":
    main()

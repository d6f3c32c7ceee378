"""Time one NovEB generation's novelty computation as the archive grows.

24 queries (parents ∪ children) against themselves plus an archive of 10^3 ... 10^6 random 64-bit codes.
Run: ``python benchmarks/bench_novelty.py [--repeats 5] [--sizes 1000 10000 ...]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from babblegen.novelty import novelty


def time_generation(archive_size: int, n_queries: int, n_words: int, k: int, repeats: int, seed: int) -> float:
    """Best-of-``repeats`` seconds for the novelty of ``n_queries`` codes against pool ∪ archive."""
    rng = np.random.default_rng(seed)
    archive = rng.integers(0, 2**64, size=(archive_size, n_words), dtype=np.uint64)
    pool = rng.integers(0, 2**64, size=(n_queries, n_words), dtype=np.uint64)
    novelty(pool, pool, archive, k)  # warm-up
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        novelty(pool, pool, archive, k)
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10**3, 10**4, 10**5, 10**6])
    parser.add_argument("--queries", type=int, default=24)
    parser.add_argument("--words", type=int, default=1, help="uint64 words per code (1 = 64-bit pHash)")
    parser.add_argument("--k", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    print(f"novelty of {args.queries} queries, {64 * args.words}-bit codes, k={args.k}, best of {args.repeats}")
    print(f"{'archive':>10} {'s/generation':>14} {'ratio':>8}")
    previous = None
    for size in args.sizes:
        t = time_generation(size, args.queries, args.words, args.k, args.repeats, args.seed)
        ratio = "" if previous is None else f"{t / previous:8.1f}"
        print(f"{size:>10d} {t:>14.5f} {ratio:>8}")
        previous = t


if __name__ == "__main__":
    main()

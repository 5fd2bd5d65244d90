"""Helpers shared by the benchmark scripts: seeding, a chunked 2-process map with a progress bar, tables.

Not a benchmark itself. The scripts import it as ``_common`` (Python puts ``bench/`` on the path when a
script there is run as ``python bench/<name>.py``).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import sys
from collections.abc import Callable, Iterator, Sequence
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

DEFAULT_WORKERS = 2


def chunk_seed(seed: int, chunk: int) -> int:
    """A Simulator seed that depends only on the run's seed and the chunk's index."""
    return int(np.random.SeedSequence([seed, chunk]).generate_state(1, dtype=np.uint32)[0])


def chunks(frames: int, size: int) -> list[tuple[int, int]]:
    """(chunk index, frame count) pairs covering ``frames`` frames in chunks of ``size``."""
    out = []
    start = 0
    while start < frames:
        n = min(size, frames - start)
        out.append((len(out), n))
        start += n
    return out


def parallel_map(
    fn: Callable[[Any], list[T]],
    tasks: Sequence[Any],
    frames_of: Callable[[Any], int],
    *,
    workers: int = DEFAULT_WORKERS,
    desc: str = "frames",
) -> Iterator[list[T]]:
    """``fn`` over ``tasks`` in ``workers`` processes, in task order, with a tqdm bar counting frames."""
    from tqdm import tqdm

    total = sum(frames_of(t) for t in tasks)
    with tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, dynamic_ncols=True) as bar:
        if workers <= 1:
            for t in tasks:
                out = fn(t)
                bar.update(frames_of(t))
                yield out
            return
        from monodock.compute import worker_pool

        with worker_pool(workers) as pool:
            for t, out in zip(tasks, pool.imap(fn, tasks), strict=True):
                bar.update(frames_of(t))
                yield out


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def simulate_chunks(
    run_chunk: Callable[[tuple[int, int, int]], list[T]], args: argparse.Namespace, desc: str, chunk: int
) -> list[T]:
    """``run_chunk((seed, chunk index, frames))`` over the run's frames in chunks, concatenated in order."""
    tasks = [(args.seed, c, n) for c, n in chunks(args.frames, chunk)]
    out: list[T] = []
    for part in parallel_map(run_chunk, tasks, lambda t: t[2], workers=args.workers, desc=desc):
        out += part
    return out


def bench_parser(doc: str, *, frames: int, frames_help: str, seed: int) -> argparse.ArgumentParser:
    """The options every benchmark shares: --frames, --seed, --out, --workers."""
    p = argparse.ArgumentParser(description=doc.split("\n\n", maxsplit=1)[0])
    p.add_argument("--frames", type=_positive, default=frames, help=f"{frames_help} (default {frames})")
    p.add_argument("--seed", type=int, default=seed, help=f"seed of the run (default {seed})")
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    p.add_argument("--workers", type=int, default=DEFAULT_WORKERS, help="render processes (default 2)")
    return p


def pin_one_cpu() -> str:
    """Time on one core from here on: OpenCV to one thread, this process to one CPU; says which ("no": not here)."""
    import cv2

    cv2.setNumThreads(1)
    if not hasattr(os, "sched_setaffinity"):
        return "no"
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return f"cpu {cpu}"


def fmt(value: float, digits: int = 2) -> str:
    """A number for a table cell ('—' for NaN)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str | None = None) -> str:
    """A GitHub markdown table; ``align`` is one letter per column, 'l' or 'r' (default: first left)."""
    align = align or "l" + "r" * (len(header) - 1)
    sep = ["---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def environment() -> dict[str, str]:
    """Versions and machine facts worth keeping with the numbers."""
    import cv2

    return {
        "date_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M"),
        "python": platform.python_version(),
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "monodock": metadata.version("monodock"),
        "machine": f"{platform.machine()}, {mp.cpu_count()} cores",
    }


def emit(report: str, raw: dict[str, Any], out: str | None) -> None:
    """Print the markdown report; with ``out``, also write it there and the raw numbers beside it (.json)."""
    print(report)
    if out:
        path = Path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(report + "\n", encoding="utf-8")
        path.with_suffix(".json").write_text(json.dumps(_clean(raw), indent=1, allow_nan=False) + "\n")
        print(f"wrote {path} and {path.with_suffix('.json')}", file=sys.stderr)


def _clean(o: Any) -> Any:
    """Raw numbers as plain JSON: numpy scalars and arrays unwrapped, NaN and infinities as null."""
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, np.bool_ | bool):
        return bool(o)
    if isinstance(o, np.integer | int):
        return int(o)
    if isinstance(o, np.floating | float):
        return float(o) if math.isfinite(float(o)) else None
    return o

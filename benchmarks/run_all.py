"""Run every benchmark and write BENCHMARKS.md (``make bench``).

Each ``benchmarks/bench_*.py`` exposes ``run(quick: bool = False) -> str`` returning a Markdown
section. Results name the machine they were measured on. Every section is also kept in
``benchmarks/results/<name>.md`` (with its run time and UTC date), so ``--assemble`` can rebuild
BENCHMARKS.md from sections measured separately (``--only`` runs) without rerunning them all.
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import sys
import time
from pathlib import Path


def machine_description() -> str:
    import psutil

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}; {os.cpu_count()} logical cores; "
            f"{psutil.virtual_memory().total / 2**30:.1f} GiB RAM; Python {platform.python_version()}; "
            f"{platform.system()} {platform.release()}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="BENCHMARKS.md")
    parser.add_argument("--only", nargs="*", help="benchmark module names (e.g. bench_ingest)")
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for smoke runs")
    parser.add_argument("--assemble", action="store_true",
                        help="write --out from benchmarks/results/*.md without running anything")
    args = parser.parse_args(argv)
    names = sorted(p.stem for p in Path(__file__).parent.glob("bench_*.py"))
    if args.only:
        names = [n for n in names if n in args.only]
    results = Path("benchmarks/results")
    sections = []
    for name in names:
        if args.assemble:
            f = results / f"{name}.md"
            sections.append(f.read_text() if f.is_file() else f"## {name}\n\n_not measured yet: run "
                            f"`python -m benchmarks.run_all --only {name}`._\n")
            continue
        t0 = time.perf_counter()
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        section = importlib.import_module(f"benchmarks.{name}").run(quick=args.quick)
        stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        section = (section.rstrip() + f"\n\n_{name} took {time.perf_counter() - t0:.0f} s "
                   f"({'quick, ' if args.quick else ''}measured {stamp})._\n")
        sections.append(section)
        results.mkdir(parents=True, exist_ok=True)
        (results / f"{name}.md").write_text(section)
    header = ("# Benchmarks\n\nProduced by `make bench` (`python -m benchmarks.run_all`). "
              f"Machine: {machine_description()}.\n\n")
    if args.assemble:
        header += ("Assembled (`--assemble`) from sections measured one at a time with `--only` on "
                   "this machine; a section's footer gives its run time and date where it has one. "
                   "Some ran while other jobs shared the two cores: wall-clock latencies (p99 most) "
                   "are then pessimistic, and ratios are always measured within one run.\n\n")
    Path(args.out).write_text(header + "\n".join(sections))
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Kept suite evaluations side by side (docs/clutter.md, docs/planning.md): each LABEL=FOLDER is an
evaluation folder (`fedjax-nav evaluate RUN --suite NAME [--out FOLDER]` writes suite_families.csv
there); one row per label and family with success [95% interval over training seeds; none with
one seed or a scripted baseline], the worst tenth of rooms, collisions, time-outs and the direct /
detour goals' success.

    python scripts/suite_table.py ideal=runs/a/eval/dense-heldout pooled=runs/b/eval/dense-heldout --csv results/x.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

COLUMNS = ["success", "ci_seeds_low", "ci_seeds_high", "worst10", "collision", "timeout"]
COLUMNS += ["success_direct", "success_detour"]


def table(pairs: list[str]) -> pd.DataFrame:
    rows = []
    for pair in pairs:
        label, _, folder = pair.partition("=")
        if not folder:
            raise SystemExit(f"error: {pair!r} is not LABEL=FOLDER")
        f = Path(folder) / "suite_families.csv"
        if not f.is_file():
            raise SystemExit(f"error: {f}: no kept suite evaluation (run `fedjax-nav evaluate RUN --suite NAME` first)")
        rows.append(pd.read_csv(f)[["family", *COLUMNS]].assign(label=label))
    return pd.concat(rows)[["label", "family", *COLUMNS]]


def markdown(t: pd.DataFrame) -> str:
    out = ["| what | family | success [seeds] | worst 10% | collision | time-out | direct goals | detour goals |"]
    out.append("|---|---|---|---|---|---|---|---|")
    for r in t.itertuples(index=False):
        ci = f"{r.success:.3f}" + ("" if pd.isna(r.ci_seeds_low) else f" [{r.ci_seeds_low:.3f}, {r.ci_seeds_high:.3f}]")
        cells = [r.label, r.family, ci, *(f"{v:.3f}" for v in (r.worst10, r.collision, r.timeout))]
        out.append("| " + " | ".join(cells + [f"{r.success_direct:.3f}", f"{r.success_detour:.3f}"]) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", metavar="LABEL=FOLDER")
    ap.add_argument("--csv", default=None, help="write the rows here")
    a = ap.parse_args(argv)
    t = table(a.pairs)
    if a.csv:
        t.to_csv(a.csv, index=False)
    print(markdown(t))
    return 0


if __name__ == "__main__":
    sys.exit(main())

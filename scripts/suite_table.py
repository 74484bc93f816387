"""Kept suite evaluations side by side (docs/clutter.md, docs/planning.md): each LABEL=FOLDER is an
evaluation folder (`fedjax-nav evaluate RUN --suite NAME [--out FOLDER]` writes suite_families.csv
there); one row per label and family with success [95% interval over training seeds; none with
one seed or a scripted baseline], the worst tenth of rooms, collisions, time-outs and the direct /
detour goals' success.

    python scripts/suite_table.py ideal=runs/a/eval/dense-heldout pooled=runs/b/eval/dense-heldout --csv results/x.csv
    python scripts/suite_table.py "4 seeds"=runs/s01/eval/dense-heldout+runs/s23/eval/dense-heldout   # pooled seeds
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

COLUMNS = ["success", "ci_seeds_low", "ci_seeds_high", "worst10", "collision", "timeout"]
COLUMNS += ["success_direct", "success_detour"]


def _kept(folder: str, name: str) -> Path:
    f = Path(folder) / name
    if not f.is_file():
        raise SystemExit(f"error: {f}: no kept suite evaluation (run `fedjax-nav evaluate RUN --suite NAME` first)")
    return f


def pooled(folders: list[str]) -> pd.DataFrame:
    """The families table of the episodes of several evaluations of one suite whose runs trained
    other seeds (e.g. seeds 0-1 and 2-3 of one config): suite_families.csv recomputed over them all."""
    import json

    from fedjax_nav.evaluation.suite import suite_families
    from fedjax_nav.evaluation.suite_stats import pool_seeds

    suites = {tuple(json.loads(_kept(f, "suite.json").read_text())["suites"]) for f in folders}
    if len(suites) > 1:
        raise SystemExit(f"error: {' + '.join(folders)}: evaluations of different suites cannot be pooled")
    try:
        ep = pool_seeds([(f, pd.read_csv(_kept(f, "suite_episodes.csv"))) for f in folders])
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    return suite_families(ep, list(dict.fromkeys(ep["family"])))


def table(pairs: list[str]) -> pd.DataFrame:
    """One row per label and family; LABEL=FOLDER1+FOLDER2 pools evaluations of other seeds."""
    rows = []
    for pair in pairs:
        label, _, folder = pair.partition("=")
        if not folder:
            raise SystemExit(f"error: {pair!r} is not LABEL=FOLDER")
        parts = folder.split("+")
        fams = pooled(parts) if len(parts) > 1 else pd.read_csv(_kept(folder, "suite_families.csv"))
        rows.append(fams[["family", *COLUMNS]].assign(label=label))
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

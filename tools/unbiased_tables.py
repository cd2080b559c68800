"""The unbiased cache's tables (issue 29) from the experiments in experiments/unbiased/.

Reads DIR/unbiased_<volume>/summary.csv for the six volumes (DIR: where the experiments wrote,
out/experiments by default), copies each summary into docs/results/unbiased/<volume>.csv (the
figures, without the images, to keep the repository light) and writes
docs/results/unbiased.md: the goal tables (the unbiased cache against NEE in efficiency at
every budget, raw and after the denoiser; its bias) and per volume every method by relMSE,
FLIP and brightness bias, raw and denoised.

    python3 tools/unbiased_tables.py [DIR]
"""

import csv
import pathlib
import shutil
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
VOLUMES = ["default", "ironprot", "hydrogen", "headsq", "chest_ct", "embryo"]
METHODS = [
    ("nee", "NEE"),
    ("cache raster", "Gaussian cache (biased, with handoff)"),
    ("cache unbiased", "Gaussian cache, unbiased (q by the rule)"),
    ("cache unbiased, q = 0.5 w", "Gaussian cache, unbiased (q = 0.5 w)"),
    ("nrc", "neural cache"),
]
BUDGETS = [
    ("spp", "1", "1 spp"),
    ("spp", "4", "4 spp"),
    ("spp", "16", "16 spp"),
    ("spp", "64", "64 spp"),
    ("seconds", "0.05", "50 ms"),
    ("seconds", "0.2", "200 ms"),
    ("seconds", "1", "1 s"),
]


def load(path):
    if not path.exists():
        return None
    with path.open() as f:
        return {(r["method"], r["budget_kind"], r["budget"]): r for r in csv.DictReader(f)}


def efficiency(r):
    return 1.0 / (float(r["rel_mse"]) * float(r["seconds"]))


def ratio_cell(rows, method, baseline, kind, b):
    """Efficiency (relMSE x time) and FLIP of `method` against `baseline`: above 1, ahead."""
    m, n = rows.get((method, kind, b)), rows.get((baseline, kind, b))
    if m is None or n is None:
        return "-"
    eff = efficiency(m) / efficiency(n)
    flip = float(n["flip"]) / float(m["flip"])
    mark = "**" if eff >= 1.5 else ""
    return f"{mark}{eff:.2f}x{mark}, {flip:.2f}x"


def cell(r):
    if r is None:
        return "-"
    bias = 100 * float(r["brightness_bias"])
    se = 100 * float(r["brightness_bias_se"])
    return f"{float(r['rel_mse']):.4f} / {float(r['flip']):.3f} / {bias:+.2f}% ({se:.2f})"


def main():
    source = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "out" / "experiments"
    (RESULTS / "unbiased").mkdir(parents=True, exist_ok=True)
    tables = {}
    for v in VOLUMES:
        path = source / f"unbiased_{v}" / "summary.csv"
        rows = load(path)
        if rows is None:
            print(f"missing {path}: skipped")
            continue
        shutil.copyfile(path, RESULTS / "unbiased" / f"{v}.csv")
        tables[v] = rows
    out = [
        "# The unbiased Gaussian cache against NEE, the biased cache and the neural cache",
        "",
        "Made by `python3 tools/unbiased_tables.py` from `experiments/unbiased/*.toml` "
        "(320x180, 3 seeds, 2 threads; figures in `docs/results/unbiased/<volume>.csv`). "
        "Ratios are NEE's over the method's: efficiency (1 / (relMSE x seconds)) and FLIP, "
        "above 1 ahead of NEE; bold where the efficiency reaches the issue's 1.5x. The "
        "denoised rows are Open Image Denoise 2.5.1 (`high`, colour alone), its time counted "
        "once per image and compared with NEE + OIDN.",
        "",
    ]
    for method, label in METHODS[1:]:
        for suffix, twin in [("", "raw"), (" + OIDN", "after the denoiser")]:
            out += [
                f"## {label}, {twin}: efficiency and FLIP against NEE{suffix}",
                "",
                "| volume | " + " | ".join(b[2] for b in BUDGETS) + " |",
                "|---|" + "---|" * len(BUDGETS),
            ]
            for v, rows in tables.items():
                out.append(
                    f"| {v} | "
                    + " | ".join(
                        ratio_cell(rows, method + suffix, "nee" + suffix, k, b)
                        for k, b, _ in BUDGETS
                    )
                    + " |"
                )
            out.append("")
    out += [
        "## Every method, per volume",
        "",
        "Each cell: relMSE / FLIP / brightness bias against the reference (its standard error "
        "over the seeds).",
        "",
    ]
    for v, rows in tables.items():
        out += [
            f"### {v}",
            "",
            "| method | " + " | ".join(b[2] for b in BUDGETS) + " |",
            "|---|" + "---|" * len(BUDGETS),
        ]
        for method, label in METHODS:
            for suffix in ["", " + OIDN"]:
                name = method + suffix
                if not any(k[0] == name for k in rows):
                    continue
                out.append(
                    f"| {label}{suffix} | "
                    + " | ".join(cell(rows.get((name, k, b))) for k, b, _ in BUDGETS)
                    + " |"
                )
        out.append("")
    path = RESULTS / "unbiased.md"
    path.write_text("\n".join(out))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

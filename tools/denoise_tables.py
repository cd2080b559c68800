"""The denoising tables (issue 28) from the committed experiment results.

Reads docs/results/<volume>/summary.csv for the six standard volumes (320x180) and their
hd_<volume> runs (1280x720) where present, and writes docs/results/denoising.md: per volume
and budget, NEE, the Gaussian cache (raster) and the neural cache, raw and after Open Image
Denoise (colour alone, and guided by the albedo), in relMSE, FLIP and PSNR-HDR; and the goal
table: the Gaussian cache + denoiser against NEE + denoiser at equal time.

    python3 tools/denoise_tables.py
"""

import csv
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
VOLUMES = ["default", "ironprot", "hydrogen", "headsq", "chest_ct", "embryo"]
METHODS = [("nee", "NEE"), ("cache raster", "Gaussian cache"), ("nrc", "neural cache")]
TWINS = [("", "raw"), (" + OIDN", "+ OIDN"), (" + OIDN (albedo)", "+ OIDN (albedo)")]


def budgets_for(prefix):
    if prefix == "hd_":
        return [("spp", "1", "1 spp"), ("spp", "4", "4 spp"), ("seconds", "0.5", "500 ms"), ("seconds", "2", "2 s")]
    return [
        ("spp", "1", "1 spp"),
        ("spp", "4", "4 spp"),
        ("seconds", "0.05", "50 ms"),
        ("seconds", "0.2", "200 ms"),
        ("seconds", "1", "1 s"),
    ]


def load(name):
    path = RESULTS / name / "summary.csv"
    if not path.exists():
        return None
    rows = {}
    with path.open() as f:
        for r in csv.DictReader(f):
            rows[(r["method"], r["budget_kind"], r["budget"])] = r
    return rows


def cell(rows, method, kind, budget):
    r = rows.get((method, kind, budget))
    if r is None:
        return "-"
    over = ""
    if kind == "seconds" and float(r["seconds"]) > 1.25 * float(budget):
        over = f" ({float(r['seconds']) * 1e3:.0f} ms)"
    flip = f"{float(r['flip']):.3f}" if r.get("flip") else "-"
    return f"{float(r['rel_mse']):.4f} / {flip} / {float(r['psnr_hdr']):.1f}{over}"


def main():
    out = [
        "# Denoised and raw: every method by relMSE, FLIP and PSNR-HDR",
        "",
        "Made by `python3 tools/denoise_tables.py` from the experiments' `summary.csv` files "
        "(3 seeds each; means over seeds). Each cell is relMSE / FLIP / PSNR-HDR (dB): lower, "
        "lower, higher is better. A twin's time counts the denoiser once per image; where the "
        "denoiser alone takes longer than the budget, the twin denoises one frame and its time "
        "is given in brackets (it does not fit). Open Image Denoise 2.5.1, `high` quality, on "
        "the CPU with the experiment's threads.",
        "",
    ]
    for prefix, title in [("", "320x180"), ("hd_", "1280x720")]:
        budgets = budgets_for(prefix)
        # Results from before the denoised twins (no `nee + OIDN` rows) are left out.
        present = [
            v
            for v in VOLUMES
            if any(k[0] == "nee + OIDN" for k in (load(prefix + v) or {}))
        ]
        if not present:
            continue
        out += [f"## {title}", ""]
        # The goal: cache + OIDN against NEE + OIDN at equal time.
        out += [
            "Goal: the Gaussian cache + denoiser ahead of NEE + denoiser. Ratios are NEE + OIDN's "
            "over the cache + OIDN's (above 1: the cache is ahead), colour-alone twins:",
            "",
            "| volume | " + " | ".join(f"{b[2]}: relMSE, FLIP" for b in budgets) + " |",
            "|---|" + "---|" * len(budgets),
        ]
        for v in present:
            rows = load(prefix + v)
            cells = []
            for kind, b, _ in budgets:
                n = rows.get(("nee + OIDN", kind, b))
                c = rows.get(("cache raster + OIDN", kind, b))
                if n is None or c is None:
                    cells.append("-")
                    continue
                rel = float(n["rel_mse"]) / float(c["rel_mse"])
                fl = float(n["flip"]) / float(c["flip"])
                mark = "**" if rel > 1 and fl > 1 else ""
                cells.append(f"{mark}{rel:.2f}x, {fl:.2f}x{mark}")
            out.append(f"| {v} | " + " | ".join(cells) + " |")
        out += ["", "(bold: ahead by both.)", ""]
        for v in present:
            rows = load(prefix + v)
            out += [
                f"### {v} ({title})",
                "",
                "| method | " + " | ".join(b[2] for b in budgets) + " |",
                "|---|" + "---|" * len(budgets),
            ]
            for m, label in METHODS:
                for suffix, twin in TWINS:
                    name = m + suffix
                    if not any(k[0] == name for k in rows):
                        continue
                    out.append(
                        f"| {label} {twin} | "
                        + " | ".join(cell(rows, name, k, b) for k, b, _ in budgets)
                        + " |"
                    )
            out.append("")
    path = RESULTS / "denoising.md"
    path.write_text("\n".join(out))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

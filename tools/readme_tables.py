"""The README's headline tables, from the committed experiment results.

Prints (Markdown) for the six standard volumes: the Gaussian cache's gains over NEE by relMSE,
its FLIP and PSNR-HDR beside NEE's, and the same comparison after Open Image Denoise; and the
neural cache's. Reads docs/results/<volume>/summary.csv and results.json (hd_<volume> with
--hd). Paste the output into README.md after a re-run.

    python3 tools/readme_tables.py [--hd]
"""

import csv
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
VOLUMES = ["default", "ironprot", "hydrogen", "headsq", "chest_ct", "embryo"]


def load(name):
    rows = {}
    with (ROOT / "docs/results" / name / "summary.csv").open() as f:
        for r in csv.DictReader(f):
            rows[(r["method"], r["budget_kind"], r["budget"])] = r
    caches = json.loads((ROOT / "docs/results" / name / "results.json").read_text())["caches"]
    return rows, {c["method"]: c for c in caches}


def f(r, key):
    return float(r[key])


def ratio(rows, a, b, kind, budget, key="rel_mse"):
    """b's metric over a's: above 1, `a` is ahead (for lower-is-better metrics)."""
    ra, rb = rows.get((a, kind, budget)), rows.get((b, kind, budget))
    if ra is None or rb is None:
        return None
    return f(rb, key) / f(ra, key)


def x(v, bold=False):
    if v is None:
        return "-"
    s = f"{v:.2f}x"
    return f"**{s}**" if bold and v > 1 else s


def main():
    hd = "--hd" in sys.argv
    prefix = "hd_" if hd else ""
    if hd:
        timed = [("seconds", "0.5", "500 ms"), ("seconds", "2", "2 s")]
        spps = [("spp", "1", "1 spp"), ("spp", "4", "4 spp")]
    else:
        timed = [("seconds", "0.05", "50 ms"), ("seconds", "0.2", "200 ms"), ("seconds", "1", "1 s")]
        spps = [("spp", "1", "1 spp"), ("spp", "64", "64 spp")]
    cols = spps[:1] + timed + spps[1:]
    print(
        "| volume | NEE relMSE, 1 spp | cache, 1 spp | "
        + " | ".join(f"cache gain {c[2]}: relMSE / FLIP / PSNR-HDR" for c in cols)
        + " | after OIDN, cache against NEE: "
        + " / ".join(c[2] for c in spps[:1] + timed)
        + " (relMSE, FLIP) | cache brightness bias | (read + train) / trace | report |"
    )
    print("|---" * (5 + len(cols) + 2) + "|")
    for v in VOLUMES:
        name = prefix + v
        try:
            rows, caches = load(name)
        except FileNotFoundError:
            continue
        n1 = rows[("nee", "spp", "1")]
        c1 = rows[("cache raster", "spp", "1")]
        cells = []
        for kind, b, _ in cols:
            g = ratio(rows, "cache raster", "nee", kind, b)
            fl = ratio(rows, "cache raster", "nee", kind, b, "flip")
            n, c = rows[("nee", kind, b)], rows[("cache raster", kind, b)]
            dp = f(c, "psnr_hdr") - f(n, "psnr_hdr")
            cells.append(f"{x(g)} / {x(fl)} / {dp:+.1f} dB")
        after = []
        for kind, b, _ in spps[:1] + timed:
            g = ratio(rows, "cache raster + OIDN", "nee + OIDN", kind, b)
            fl = ratio(rows, "cache raster + OIDN", "nee + OIDN", kind, b, "flip")
            both = g is not None and fl is not None and g > 1 and fl > 1
            after.append(f"{x(g, both)}, {x(fl, both)}")
        bias_budget = ("spp", "4") if hd else ("spp", "16")
        bb = rows[("cache raster",) + bias_budget]
        c = caches["cache raster"]
        overhead = (c["splat_ms"] + c["train_ms"]) / c["trace_ms"]
        print(
            f"| {v} | {f(n1, 'rel_mse'):.4f} | {f(c1, 'rel_mse'):.4f} | "
            + " | ".join(cells)
            + f" | {' / '.join(after)} | {100 * f(bb, 'brightness_bias'):+.1f}% ± "
            f"{100 * f(bb, 'brightness_bias_se'):.1f}% | {overhead:.2f}x | "
            f"[report](docs/results/{name}/report.md) |"
        )
    print()
    print(
        "| volume | "
        + " | ".join(f"nrc / Gaussian gain {c[2]}: relMSE, FLIP" for c in cols)
        + " | after OIDN, nrc against NEE: "
        + " / ".join(c[2] for c in spps[:1] + timed)
        + " (relMSE, FLIP) |"
    )
    print("|---" * (2 + len(cols)) + "|")
    for v in VOLUMES:
        try:
            rows, _ = load(prefix + v)
        except FileNotFoundError:
            continue
        cells = []
        for kind, b, _ in cols:
            gn = ratio(rows, "nrc", "nee", kind, b)
            gc = ratio(rows, "cache raster", "nee", kind, b)
            fn = ratio(rows, "nrc", "nee", kind, b, "flip")
            fc = ratio(rows, "cache raster", "nee", kind, b, "flip")
            cells.append(f"{x(gn)}, {x(fn)} / {x(gc)}, {x(fc)}")
        after = []
        for kind, b, _ in spps[:1] + timed:
            g = ratio(rows, "nrc + OIDN", "nee + OIDN", kind, b)
            fl = ratio(rows, "nrc + OIDN", "nee + OIDN", kind, b, "flip")
            after.append(f"{x(g)}, {x(fl)}")
        print(f"| {v} | " + " | ".join(cells) + f" | {' / '.join(after)} |")


if __name__ == "__main__":
    main()

"""Spectral estimation and material identification: held-out accuracy, identification, speed.

Held-out evaluation (the issue's protocol): the estimators are trained on
the 190 RAW to ACES training reflectances less their near-duplicates of the
ColorChecker (RMS difference < 0.0125, :mod:`processing.spectral.reflectance_database`)
and tested on the 24 ColorChecker N Ohta patches, camera Nikon 5100 (NPL),
400-700 nm at 5 nm.  Noise: every channel of every test sample gets
Gaussian noise of 1 % of its value (20 noisy draws per patch, seeded); the
chart used for the camera transfer is the mean of a patch (100 pixels), so
0.1 %.  Figures: spectral RMSE (reflectance), mean GFC (goodness-of-fit
coefficient, the cosine between spectra), mean and 90th-percentile CIEDE2000
between the estimated and true reflectance lit by D65 and by illuminant A
(CIE 1931 2 degree observer, white = the perfect diffuser under that light).

Rows: the paper's method (PCA p = 3, M by least squares: the baseline),
Wiener (1 % noise model), root-polynomial (degree 2, 8 PCA weights, ridge by
cross-validation), more-basis (linear, 8 PCA weights, ridge), two lights
(D65 and A exposures, six channels, root-polynomial onto 10 weights), the
camera transfer (a second camera: the Nikon's sensitivities shifted by
+10 nm; its chart shot gives M2 and the root-polynomial estimator trained for
the Nikon is used through it), and Wiener with the Nikon's sensitivities
estimated from the (noisy) chart shot (:mod:`processing.camera.from_chart`).

Identification: every candidate of
:data:`processing.materials.identification.DEFAULT_CANDIDATES`, camera values
from the material's own spectral factors (:func:`material_brdf` at normal
view, light at 30 degrees), random brightness, 1 % noise per pixel; regions
of 1, 25 and 100 pixels and single pixels of two exposures (D65 and A), 200
trials each.  Alloy weights: Table 1 alloys,
Ag fraction error over 200 regions of 1 and of 100 pixels.

Speed: a 6000 x 4000 (24 MP) float32 linear camera image to basis weights,
median of 5 runs after a warm-up, peak resident memory of the process.

``python -m bench.spectral_bench`` runs both cases in fresh processes and
prints one JSON line; ``--case accuracy`` / ``--case speed`` run one.
:func:`section` turns the results into the Markdown of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

__all__ = ["measure_accuracy", "measure_identification", "measure_speed", "collect", "section", "main"]

NOISE = 0.01
DRAWS = 20
CHART_NOISE = 0.001
SHIFTS_NM = (5.0, 10.0)
TARGETS = {
    "single_d65": 1.2,
    "single_a": 1.5,
    "two_a": 0.8,
    "two_rmse": 0.035,
    "transfer_ratio": 1.5,
    "identification": 0.95,
    "alloy_points": 5.0,
    "seconds": 3.0,
    "memory_gb": 3.0,
}


def _setup():
    from processing.camera.response import camera_sensitivities
    from processing.spectral.reflectance_database import load_reflectances, without_near_duplicates
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    g = REFERENCE_GRID
    train = load_reflectances("training", g)
    chart = load_reflectances("colorchecker", g)
    held = without_near_duplicates(train, chart)
    return {
        "grid": g,
        "train": held.spectra,
        "removed": len(train) - len(held),
        "test": chart.spectra,
        "sens": np.array(camera_sensitivities(g)),
        "d65": light_spectrum("D65", g),
        "a": light_spectrum("A", g),
    }


def _shifted(sens: np.ndarray, grid, shift_nm: float) -> np.ndarray:
    """The sensitivities moved by ``shift_nm`` along wavelength (held at the ends)."""
    wl = grid.wavelengths
    return np.stack([np.interp(wl - shift_nm, wl, sens[:, c]) for c in range(sens.shape[1])], axis=1)


def _metrics(est: np.ndarray, truth: np.ndarray, s: dict) -> dict[str, float]:
    from processing.spectral.display import delta_e00, spectra_to_xyz

    g = s["grid"]
    out = {"rmse": float(np.sqrt(np.mean((est - truth) ** 2)))}
    num = np.sum(est * truth, axis=1)
    den = np.linalg.norm(est, axis=1) * np.linalg.norm(truth, axis=1)
    out["gfc"] = float(np.mean(num / np.maximum(den, 1e-300)))
    for key, light in (("d65", s["d65"]), ("a", s["a"])):
        white = spectra_to_xyz(light, g)
        de = delta_e00(spectra_to_xyz(est * light, g), spectra_to_xyz(truth * light, g), white)
        out[f"de_{key}_mean"] = float(np.mean(de))
        out[f"de_{key}_p90"] = float(np.percentile(de, 90))
    return out


def _noisy(rho: np.ndarray, level: float, rng: np.random.Generator, draws: int) -> np.ndarray:
    return np.concatenate([np.maximum(rho * (1 + level * rng.standard_normal(rho.shape)), 0.0) for _ in range(draws)])


def measure_accuracy(seed: int = 0) -> dict:
    """The held-out table (see the module text)."""
    from processing.camera.from_chart import estimate_sensitivities
    from processing.camera.response import camera_rgb
    from processing.spectral.estimation.estimator import fit_estimator

    s = _setup()
    g, db, test, sens = s["grid"], s["train"], s["test"], s["sens"]
    truth = np.tile(test, (DRAWS, 1))
    rows = []

    def run(name: str, fit, rho_clean: np.ndarray, note: str, rng_seed: int) -> dict:
        rng = np.random.default_rng(rng_seed)
        est = fit.estimate_spectra(_noisy(rho_clean, NOISE, rng, DRAWS))
        r = {"row": name, "note": note, **_metrics(est, truth, s)}
        rows.append(r)
        return r

    rho_d65 = camera_rgb(test, s["d65"], sens, g)
    for name in ("paper", "wiener", "rootpoly", "more-basis"):
        fit = fit_estimator(name, db, sens, s["d65"], g, noise=NOISE)
        run(name, fit, rho_d65, f"p = {fit.p}", seed)
    lights = np.stack([s["d65"], s["a"]])
    two = fit_estimator("twolight", db, sens, lights, g, noise=NOISE)
    run("twolight", two, camera_rgb(test, lights, sens, g), f"D65 + A, p = {two.p}", seed)

    # a second camera: the Nikon shifted along wavelength; it is calibrated from its own chart shot (patch means)
    rng = np.random.default_rng(seed + 1)
    for shift in SHIFTS_NM:
        other = _shifted(sens, g, shift)
        rho_other = camera_rgb(test, s["d65"], other, g)
        chart_other = rho_other * (1 + CHART_NOISE * rng.standard_normal((24, 3)))
        transfer = fit_estimator("rootpoly", db, sens, s["d65"], g, noise=NOISE,
                                 chart_rgb=chart_other, chart_reflectance=test)
        run(f"camera-transfer +{shift:g} nm, M2", transfer, rho_other,
            f"rootpoly for the Nikon through M2 (chart condition {transfer.condition['chart']:.1f})", seed)
        guessed = estimate_sensitivities(chart_other, test, s["d65"], g, noise=CHART_NOISE)
        own = fit_estimator("rootpoly", db, guessed.sensitivities, s["d65"], g, noise=NOISE)
        run(f"camera-transfer +{shift:g} nm, camera from chart", own, rho_other,
            "rootpoly trained for the sensitivities estimated from the second camera's chart shot", seed)
        known = fit_estimator("rootpoly", db, other, s["d65"], g, noise=NOISE)
        run(f"second camera +{shift:g} nm, known sensitivities", known, rho_other,
            "bound: rootpoly trained for the second camera's true sensitivities", seed)

    # the camera unknown: sensitivities from the chart shot, then Wiener with them
    chart_nikon = rho_d65 * (1 + CHART_NOISE * rng.standard_normal((24, 3)))
    est_sens = estimate_sensitivities(chart_nikon, test, s["d65"], g, noise=CHART_NOISE)
    wiener_est = fit_estimator("wiener", db, est_sens.sensitivities, s["d65"], g, noise=NOISE)
    rel = np.linalg.norm(est_sens.sensitivities - sens, axis=0) / np.linalg.norm(sens, axis=0)
    run("wiener, camera from chart", wiener_est, rho_d65,
        f"sensitivities from the chart (condition {est_sens.condition:.1f}, L2 error "
        f"{', '.join(f'{100 * x:.0f}%' for x in rel)})", seed)
    return {"rows": rows, "removed": s["removed"], "train": int(db.shape[0])}


def measure_identification(seed: int = 0, trials: int = 200) -> dict:
    """Identification accuracy per material and the alloy Ag-fraction error (see the module text)."""
    from processing.camera.response import camera_rgb
    from processing.materials.alloys import ALLOY_COMPOSITIONS
    from processing.materials.identification import (
        DEFAULT_CANDIDATES,
        NEUTRAL_METAL,
        candidate_set,
        estimate_alloy_weights,
        identify_material,
    )
    from processing.materials.lobes import material_brdf
    from processing.materials.metal_model import ConductorFresnel
    from processing.materials.presets import get_material

    s = _setup()
    g, sens, e = s["grid"], s["sens"], s["d65"]
    light_deg = 30.0
    cos_i, cos_d = np.cos(np.radians(light_deg)), np.cos(np.radians(light_deg / 2))
    cands = candidate_set(sens, e, g, light_deg=light_deg)
    lights2 = np.stack([e, s["a"]])
    cands2 = candidate_set(sens, lights2, g, light_deg=light_deg)
    rng = np.random.default_rng(seed)
    sizes = (1, 25, 100)
    per_material = []
    for name in DEFAULT_CANDIDATES:
        brdf = material_brdf(get_material(name), cos_i, 1.0, cos_d, cos_d, g.wavelengths)
        truth = camera_rgb(brdf * cos_i, e, sens, g)
        row = {"material": name, "neutral": bool(cands.neutral[cands.names.index(name)])}
        for n in sizes:
            ok, neutral_answers, conf = 0, 0, []
            for _ in range(trials):
                px = truth * rng.uniform(0.1, 3.0) * (1 + NOISE * rng.standard_normal((n, 3)))
                r = identify_material(px, cands, noise=NOISE)
                right = r.material == name or (r.material == NEUTRAL_METAL and name in r.group)
                ok += right
                neutral_answers += r.material == NEUTRAL_METAL
                conf.append(r.confidence)
            row[f"acc_{n}"] = ok / trials
            row[f"neutral_{n}"] = neutral_answers / trials
            row[f"conf_{n}"] = float(np.mean(conf))
        # single pixels from two exposures (D65 and A): six channels
        truth2 = camera_rgb(brdf * cos_i, lights2, sens, g)
        ok = 0
        for _ in range(trials):
            r = identify_material(truth2 * rng.uniform(0.1, 3.0) * (1 + NOISE * rng.standard_normal((1, 6))),
                                  cands2, noise=NOISE)
            ok += r.material == name or (r.material == NEUTRAL_METAL and name in r.group)
        row["acc_1_twolight"] = ok / trials
        per_material.append(row)
    alloys = []
    for name, comp in ALLOY_COMPOSITIONS.items():
        if "Sn" in comp:
            continue
        total = sum(comp.values())
        frac = {k: v / total for k, v in comp.items()}
        rgb = camera_rgb(ConductorFresnel(frac).reflectance(cos_d, g.wavelengths), e, sens, g)
        row = {"alloy": name, "ag": frac.get("Ag", 0.0)}
        for n in (1, 100):
            err = []
            for _ in range(trials):
                px = rgb * rng.uniform(0.1, 3.0) * (1 + NOISE * rng.standard_normal((n, 3)))
                err.append(estimate_alloy_weights(px, sens, e, g, light_deg=light_deg, noise=NOISE).as_dict()["Ag"]
                           - frac.get("Ag", 0.0))
            err = np.abs(np.array(err)) * 100
            row[f"mean_pts_{n}"] = float(err.mean())
            row[f"p95_pts_{n}"] = float(np.percentile(err, 95))
            row[f"max_pts_{n}"] = float(err.max())
        alloys.append(row)
    return {"materials": per_material, "alloys": alloys, "sizes": list(sizes), "trials": trials}


def measure_speed(height: int = 4000, width: int = 6000, repeats: int = 5) -> dict:
    """24 MP float32 image to weights: median seconds per method, peak RSS (see the module text)."""
    from bench.common import median_time, peak_rss_mb
    from processing.spectral.estimation.estimator import fit_estimator

    s = _setup()
    g = s["grid"]
    img = np.random.default_rng(0).uniform(0.0, 1.0, (height, width, 3)).astype(np.float32)
    out = {"pixels": height * width, "methods": []}
    for name in ("paper", "rootpoly"):
        fit = fit_estimator(name, s["train"], s["sens"], s["d65"], g, noise=NOISE)
        fit.estimate_weights(img[:64])                       # warm-up
        med, times = median_time(lambda fit=fit, img=img: fit.estimate_weights(img), repeats)
        out["methods"].append({"method": name, "p": fit.p, "seconds": med, "times": times})
    del img
    img6 = np.random.default_rng(1).uniform(0.0, 1.0, (height, width, 6)).astype(np.float32)
    two = fit_estimator("twolight", s["train"], s["sens"], np.stack([s["d65"], s["a"]]), g, noise=NOISE)
    med, times = median_time(lambda: two.estimate_weights(img6), repeats)
    out["methods"].append({"method": "twolight", "p": two.p, "seconds": med, "times": times})
    out["peak_rss_mb"] = peak_rss_mb()
    with open("/proc/loadavg", encoding="ascii") as fh:
        out["load_average"] = float(fh.read().split()[0])
    return out


def _verdict(value: float, limit: float) -> str:
    if value <= limit:
        return "met"
    return f"**not met** (+{100 * (value / limit - 1):.0f}%)"


def section(results: dict) -> list[str]:
    """Markdown for docs/BENCHMARKS.md from the JSON of :func:`main`."""
    acc, ident, speed = results["accuracy"], results["identification"], results["speed"]
    t = TARGETS
    lines = [
        "## Spectral estimation and material identification",
        "",
        f"`bench/spectral_bench.py`.  Run on: {results['machine']}.",
        "",
        "### Held-out spectral estimation",
        "",
        f"Trained on the 190 RAW to ACES training reflectances less {acc['removed']} near-duplicates of the test chart",
        f"({acc['train']} spectra), tested on ColorChecker N Ohta (24 patches x {DRAWS} noisy draws), camera Nikon 5100",
        "(NPL), 400-700 nm at 5 nm, 1 % Gaussian noise on every channel (relative to its value).  dE00: CIEDE2000",
        "of the estimated against the true reflectance under D65 and under A.  Targets: one shot mean dE00 <= "
        f"{t['single_d65']} (D65) and <= {t['single_a']} (A); two lights mean dE00 <= {t['two_a']} (A) and RMSE <= "
        f"{t['two_rmse']}; the camera transfer within {t['transfer_ratio']}x of the reference camera's error.",
        "",
        "| method | RMSE | GFC | dE00 D65 mean | p90 | dE00 A mean | p90 | target | notes |",
        "|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    by = {r["row"]: r for r in acc["rows"]}
    ref = by["rootpoly"]
    for r in acc["rows"]:
        if r["row"] == "twolight":
            verdict = (f"A: {_verdict(r['de_a_mean'], t['two_a'])}; RMSE: {_verdict(r['rmse'], t['two_rmse'])}")
        elif r["row"].startswith("camera-transfer"):
            ratio = max(r["de_d65_mean"] / ref["de_d65_mean"], r["de_a_mean"] / ref["de_a_mean"])
            verdict = f"{ratio:.2f}x Nikon rootpoly: {_verdict(ratio, t['transfer_ratio'])}"
        elif r["row"].startswith("second camera"):
            ratio = max(r["de_d65_mean"] / ref["de_d65_mean"], r["de_a_mean"] / ref["de_a_mean"])
            verdict = f"({ratio:.2f}x Nikon rootpoly)"
        else:
            verdict = (f"D65: {_verdict(r['de_d65_mean'], t['single_d65'])}; "
                       f"A: {_verdict(r['de_a_mean'], t['single_a'])}")
        name = f"{r['row']} (baseline)" if r["row"] == "paper" else r["row"]
        lines.append(f"| {name} | {r['rmse']:.4f} | {r['gfc']:.4f} | {r['de_d65_mean']:.2f} | {r['de_d65_p90']:.2f} | "
                     f"{r['de_a_mean']:.2f} | {r['de_a_p90']:.2f} | {verdict} | {r['note']} |")
    bound = {r["row"].split(",")[0].replace("second camera ", ""): r for r in acc["rows"] if r["row"].startswith("second camera")}
    why = [
        "",
        "Why targets are missed.  The paper's method, Wiener and more-basis are linear maps from three values to a",
        "spectrum; only the root-polynomial terms bring the one-shot error under the D65 target.  Two lights: the",
        f"RMSE is limited by the {acc['train']} training spectra (five-fold cross-validation on them alone gives about",
        "0.050 and also favours 10 basis vectors).  Camera transfer: the target compares",
        "the second camera with the Nikon, but a camera with shifted sensitivities is itself a worse colorimeter --",
        "trained for its own true sensitivities it already errs by the 'known sensitivities' rows.  Against that",
        "bound:",
        "",
    ]
    for shift, b in bound.items():
        for r in acc["rows"]:
            if r["row"].startswith(f"camera-transfer {shift}"):
                why.append(f"* {r['row']}: {r['de_d65_mean'] / b['de_d65_mean']:.2f}x (D65) and "
                           f"{r['de_a_mean'] / b['de_a_mean']:.2f}x (A) that camera's own bound.")
    why += ["", "Estimating the second camera from its chart shot reaches the bound; a 3 x 3 M2 does not."]
    lines += why
    lines += [
        "",
        "### Material identification and alloy weights",
        "",
        "Camera values from each material's own spectral factors at normal view with the light at 30 deg",
        f"(Nikon 5100, D65), random brightness x0.1-3, 1 % noise per pixel; {ident['trials']} trials per cell.",
        "A 'neutral metal' answer counts as right when the true metal is in the reported group.",
        f"Target: >= {100 * t['identification']:.0f} % for gold, copper, the shibuichi series, shakudo, bronze.",
        "",
        "| material | 1 pixel | 25 pixels | 100 pixels | 1 pixel, D65 + A exposures | mean confidence (1 / 25 / 100) | "
        "'neutral metal' answers (1 px) |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    for m in ident["materials"]:
        lines.append(f"| {m['material']}{' (neutral)' if m['neutral'] else ''} | {100 * m['acc_1']:.1f}% | "
                     f"{100 * m['acc_25']:.1f}% | {100 * m['acc_100']:.1f}% | {100 * m['acc_1_twolight']:.1f}% | "
                     f"{m['conf_1']:.2f} / {m['conf_25']:.2f} / {m['conf_100']:.2f} | {100 * m['neutral_1']:.0f}% |")
    targeted = [m for m in ident["materials"]
                if m["material"] in ("gold", "copper", "shakudo", "bronze") or "shibuichi" in m["material"]]
    for n in ident["sizes"]:
        worst = min(targeted, key=lambda m: m[f"acc_{n}"])
        lines.append("")
        lines.append(f"Regions of {n} pixel{'s' if n > 1 else ''}: worst targeted material {worst['material']} "
                     f"{100 * worst[f'acc_{n}']:.1f}% -> "
                     + ("met" if worst[f"acc_{n}"] >= t["identification"] else "**not met**") + ".")
    lines += [
        "",
        f"Alloy Ag fraction (weights of Ag, Cu, Au, non-negative, sum 1), error in percentage points; target +-{t['alloy_points']:g}.",
        "",
        "| alloy | Ag (Table 1) | 1 px mean / p95 / max | 100 px mean / p95 / max | target (100 px max) |",
        "|---|---:|---|---|---|",
    ]
    for a in ident["alloys"]:
        lines.append(f"| {a['alloy']} | {100 * a['ag']:.1f}% | {a['mean_pts_1']:.2f} / {a['p95_pts_1']:.2f} / "
                     f"{a['max_pts_1']:.2f} | {a['mean_pts_100']:.2f} / {a['p95_pts_100']:.2f} / {a['max_pts_100']:.2f} | "
                     f"{_verdict(a['max_pts_100'], t['alloy_points'])} |")
    lines += [
        "",
        "### Speed: 24 MP image to basis weights",
        "",
        f"{speed['pixels'] / 1e6:.0f} MP float32 linear camera image (6 channels for two lights) to float32 weights,",
        f"median of 5 after a warm-up; 1-minute load average at the end {speed['load_average']:.1f} on 2 cores",
        f"(shared machine).  Target: <= {t['seconds']:g} s, peak memory <= {t['memory_gb']:g} GB.",
        "",
        "| method | basis p | median (s) | fastest (s) | runs (s) | target (median) |",
        "|---|---:|---:|---:|---|---|",
    ]
    for m in speed["methods"]:
        lines.append(f"| {m['method']} | {m['p']} | {m['seconds']:.2f} | {min(m['times']):.2f} | "
                     f"{', '.join(f'{x:.2f}' for x in m['times'])} | {_verdict(m['seconds'], t['seconds'])} |")
    mem = speed["peak_rss_mb"] / 1024
    lines += ["", f"Peak resident memory of the process (image, weights, temporaries): {mem:.2f} GB: "
              f"{_verdict(mem, t['memory_gb'])}.", ""]
    return lines


def collect() -> dict:
    """Both cases, each in a fresh process, and the machine: the input of :func:`section`."""
    from bench.common import machine_description, run_case_subprocess

    a = run_case_subprocess("bench.spectral_bench", "accuracy")
    return {"accuracy": a["accuracy"], "identification": a["identification"],
            "speed": run_case_subprocess("bench.spectral_bench", "speed"), "machine": machine_description()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=("accuracy", "speed"), default=None)
    parser.add_argument("--markdown", action="store_true", help="print the Markdown section instead of JSON")
    args = parser.parse_args(argv)
    if args.case == "accuracy":
        print(json.dumps({"accuracy": measure_accuracy(), "identification": measure_identification()}))
        return 0
    if args.case == "speed":
        print(json.dumps(measure_speed()))
        return 0
    results = collect()
    if args.markdown:
        print("\n".join(section(results)))
    else:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())

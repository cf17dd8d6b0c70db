"""`kogei demo` end to end at a small size, checked against physics rather than against itself."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from app.cli import main


def test_demo_writes_images_and_alloys_shift_more_than_neutral_metals(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--hawk-triangles", "6000", "--size", "240x180", "--preset", "draft",
                 "--capture-steps", "60", "--capture-passes", "2", "--capture-camera", "hotfolder"])
    err = capsys.readouterr().err
    assert code == 0, err
    for name in ("hawk.png", "hawk.tiff", "spheres-D65.png", "spheres-A.png", "spheres-A-unadapted.png"):
        assert (out / name).stat().st_size > 1000, name
    hawk = np.asarray(Image.open(out / "hawk.png"))
    assert hawk.shape == (180, 240, 3)
    assert hawk.std() > 5        # an object, not a blank frame

    # every product, whichever of the two processes wrote it (the stages moved between them since)
    assert {"capture", "colour", "demo.json", "hawk.png", "hawk.tiff", "hawk.glb", "hawk-measured.png", "probe.exr",
            "probe.json", "hawk-probe.png", "hawk-sky.png", "spheres-D65.png", "spheres-D65.tiff", "spheres-A.png",
            "spheres-A.tiff", "spheres-A-unadapted.png", "cloth-silk.png", "cloth-tamamushi.png"} <= {
        p.name for p in out.iterdir()}
    assert {"calibration", "camera-calibration", "lamp-calibration", "session", "capture-profiles.png"} <= {
        p.name for p in (out / "capture").iterdir()}
    for name in ("identify.json", "spectra.png"):
        assert (out / "colour" / name).stat().st_size > 0, name

    summary = json.loads((out / "demo.json").read_text())
    # every stage's seconds are in the summary, and the whole demo's
    stages = summary["stages_s"]
    assert {"scanner calibration (sphere scan)", "camera and lamp calibration", "capture session (profiles, RAW frames)",
            "process (register, mesh, pose frames)", "batch (colour, materials, render, report)",
            "measured object (materials, glTF, render)", "light", "light probe (shots, merge, unwrap)",
            "colour (RAW frames, chart, identification)", "hawk render", "spheres (D65 and A)", "cloth"} == set(stages)
    assert all(v > 0 for v in stages.values()) and summary["seconds"] > 0
    cap = summary["capture"]
    manifest = json.loads((out / "capture" / "session" / "session.json").read_text())
    assert manifest["status"] == "complete" and cap["captures_taken"] == 2 * (1 + 60 + 12)
    assert sum(r["kind"] == "chart" for r in manifest["captures"].values()) == 2
    # single placements have holes (occlusion, specular dropouts) but see the object
    assert all(0.05 < f < 0.95 for f in cap["valid_fraction_per_pass"])
    assert (out / "capture" / "capture-profiles.png").stat().st_size > 5000
    # the scanner was calibrated from a sphere scan, close to the simulated station's true pose
    assert cap["calibration"]["error_vs_truth"]["rotation_deg"] < 0.05
    assert cap["calibration"]["error_vs_truth"]["translation_mm"] < 0.05
    proc = cap["process"]
    assert proc["mesh"]["watertight"] and all(proc["registered"])
    # the second pass lands where the simulation put it (a coarse bound: 60 steps, draft preset)
    assert all(e["rotation_deg"] < 1.0 and e["translation_mm"] < 1.0 for e in proc["pose_error_vs_truth"])
    assert (out / "capture" / "session" / "products" / "mesh.ply").stat().st_size > 10_000
    # the camera was calibrated from the board session and tied to the turntable by the sphere's photos;
    # against the simulation's truth (targets: focal 0.2 %, pose 0.05 deg and 0.2 mm)
    station = cap["station"]
    cam = station["camera"]
    assert cam["rms_px"] <= 0.3 and cam["frames_used"] >= 6
    assert abs(cam["error_vs_truth"]["focal_pct"]) <= 0.2
    assert cam["error_vs_truth"]["rotation_deg"] <= 0.05
    assert cam["error_vs_truth"]["translation_mm"] <= 0.2
    # the station's distant lamp located from the chrome sphere's highlights (target 0.2 deg)
    (lamp,) = station["lamps"]["error_vs_truth"]
    assert lamp["kind"] == "distant" and lamp["direction_error_deg"] <= 0.2
    # every RAW frame posed on the mesh: the mesh's outline lies on the object's outline in every photo
    proj = proc["projection"]
    assert proj["frames"] == 2 * 12
    assert proj["iou_min"] >= 0.98 and proj["offset_px_mean"] <= 0.5
    session = out / "capture" / "session"
    from processing.appearance.observations import per_vertex_counts, read_observations

    obs = read_observations(session / "products" / "observations.npz")
    assert len(obs) == proj["observations"] and (per_vertex_counts(obs) > 0).mean() > 0.9
    # the session's colour, render and report steps ran through the batch; the report is one HTML file
    assert summary["batch"]["status"] == "ok", summary["batch"]
    html = (out / "capture" / "session" / "products" / "report.html").read_text()
    assert "<img" in html and 'src="http' not in html
    assert "Every photo posed on the mesh" in html and "alt='overlays of every posed frame'" in html
    assert "held at nominal values (long lens)</th><td>cx, cy, k2, p1, p2" in html
    # materials measured on the mesh: regions with answers, held-out photos compared, exported, rendered
    obj = summary["object"]
    assert obj["regions"] and all(r["material"] for r in obj["regions"])
    # At this small size (240 x 180, the lens spreading a point over about a photosite) the head's silver (truth
    # 25.0 % Ag) measures 27.4 +- 3 % (25.9 % through a pinhole), just past the midpoint (27.35 %) to the
    # uchi-sanbu preset (29.7 %): the name may go either way, the measurement may not.  The alloy target
    # (+-3 points) holds, a wrong name is not confident and lists the truth; the lacquer and gold are found.
    doc = json.loads((session / "products" / "object-materials.json").read_text())
    head = max(doc["regions"], key=lambda r: r.get("area_mm2") or 0.0)
    assert abs(head["parameters"]["Ag"] - 0.25) <= 0.03, head["parameters"]
    assert head["material"] == "nami-shibuichi" or (head["confidence"] < 0.9 and "nami-shibuichi" in head["group"])
    share = obj["agreement"]["per_true_material"]
    assert share["urushi-black"] >= 0.8 and share["gold"] >= 0.4, share      # measured 0.90 and 0.55
    assert obj["validation"]["mean_de2000"] > 0 and obj["validation"]["baseline_mean_de2000"] > 0
    assert (out / "hawk.glb").read_bytes()[:4] == b"glTF"
    assert np.asarray(Image.open(out / "hawk-measured.png")).std() > 5
    assert "Materials on the mesh" in html and "Held-out photos" in html
    # measured light: a simulated probe of the room of known light, and the measured hawk under it and under a sky
    from processing.lighting.environment_map import read_environment

    light = summary["light"]
    env = read_environment(out / "probe.exr")
    assert env.height == light["map"][0] and np.isfinite(env.pixel_luminance()).all()
    assert env.pixel_luminance().max() > 10 * np.median(env.pixel_luminance())     # the lamps stand out
    # against the room's truth (targets: luminance within 5 %; measured 0.99 for the lamps, window, floor and ceiling)
    for name in ("floor", "ceiling", "window", "lamp 1", "lamp 2", "lamp 3"):
        assert abs(light["regions"][name]["luminance_ratio"] - 1.0) < 0.05, name
    assert abs(light["total_luminance_ratio"] - 1.0) < 0.05
    # two bracket sets (the second through a filter) and the chart's light as measured bring the coloured walls
    # within the target too (measured 0.0009 / 0.0023 / 0.0040 / 0.0025); one set reads the red wall 0.023 off
    for name in ("red wall", "green wall", "blue wall", "yellow wall"):
        assert light["regions"][name]["dxy"] <= 0.005, name
        assert abs(light["regions"][name]["luminance_ratio"] - 1.0) < 0.05, name
    assert light["one_set"]["regions"]["red wall"]["dxy"] > 0.01
    assert env.coefficients.shape[2] == light["components"] == 6
    assert light["hawk"] == "the measured hawk"
    for name in ("hawk-probe.png", "hawk-sky.png"):
        img = np.asarray(Image.open(out / name))
        assert img.shape == (90, 120, 3) and img.std() > 5, name
    # the room's coloured walls and lamps light the hawk differently from the neutral sky
    assert np.abs(np.asarray(Image.open(out / "hawk-probe.png")).astype(float)
                  - np.asarray(Image.open(out / "hawk-sky.png")).astype(float)).mean() > 5
    # the hawk's materials from RAW frames calibrated by the chart, against the simulation's truth
    regions = {r["region"]: r for r in summary["colour"]["regions"]}
    assert regions["beak"]["true_material"] == "gold" and regions["beak"]["material"] == "gold"
    assert summary["colour"]["correct"] == sum(r["material"] == r["true_material"] for r in regions.values())
    # the woven cloth scenes (Yasuda et al.) show a lit sheet, not a blank frame
    for cloth in ("silk", "tamamushi"):
        img = np.asarray(Image.open(out / f"cloth-{cloth}.png"))
        assert img.std() > 5, cloth
    shift = summary["shift_D65_to_A"]
    # After adaptation to each light's white, a spectrally flat reflector looks the same under both
    # lights; a reflectance that rises steeply in the red (copper, bronze, shakudo) does not.
    neutral = max(shift["silver"], shift["aluminium"])
    for coloured in ("copper", "bronze", "shakudo"):
        assert shift[coloured] > 2 * neutral, (coloured, shift[coloured], neutral)
    assert neutral < 0.6

    # Unadapted, tungsten light makes the whole frame warm: red well above blue on average.
    warm = np.asarray(Image.open(out / "spheres-A-unadapted.png")).astype(float).reshape(-1, 3).mean(0)
    assert warm[0] > warm[2] + 40

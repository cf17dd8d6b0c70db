"""Metal fractions near the float limit keep their shares; a roughness below 1e-5 is refused by every reader."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli import main
from app.workflows._materials_document import materials_document_problem
from processing.materials.metal_model import metal_material, normalise_composition
from processing.materials.microfacet import MIN_ROUGHNESS, microfacet_lobe
from processing.materials.presets import MaterialError, check_material_spec, get_material


def test_huge_fractions_are_normalised_without_overflow():
    assert normalise_composition({"Ag": 1e308, "Cu": 1e308}) == {"Ag": 0.5, "Cu": 0.5}
    m = get_material("nami-shibuichi:Ag=1e308,Cu=1e308")
    assert m.parameters["Ag"] == 0.5 and m.parameters["Cu"] == 0.5
    shares = [v for k, v in m.parameters.items() if k in ("Ag", "Cu")]
    assert all(0.0 <= v <= 1.0 for v in shares)


def test_materials_command_shows_the_shares_not_black(capsys):
    assert main(["materials", "nami-shibuichi:Ag=1e308,Cu=1e308"]) == 0
    out = capsys.readouterr().out
    assert "sRGB under D65: #000000" not in out
    assert "Ag                        0.5" in out


@pytest.mark.parametrize("spec, key", [("gold:roughness=1e-320", "roughness"),
                                       ("urushi-red:mirror_roughness=1e-9", "mirror_roughness")])
def test_roughness_below_the_floor_is_refused(spec, key, capsys):
    with pytest.raises(MaterialError, match=rf"{key} \(Beckmann RMS slope\) must be a finite number >= 1e-05"):
        get_material(spec)
    assert main(["materials", spec]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "1e-05" in err and "mirror_roughness=0.01" in err, err


def test_the_floor_is_shared_by_builders_and_the_model():
    assert MIN_ROUGHNESS == 1e-5
    with pytest.raises(ValueError, match="roughness .* >= 1e-05"):
        metal_material("gold", {"Au": 1.0}, roughness=1e-320)
    with pytest.raises(ValueError, match=">= 1e-05"):
        microfacet_lobe(0.5, 0.5, 1.0, 0.5, 1e-320)
    v = microfacet_lobe(np.array([0.5, 0.9]), np.array([0.5, 0.9]), np.array([1.0, 0.99]), 0.5, MIN_ROUGHNESS)
    assert np.all(np.isfinite(v))
    assert check_material_spec("gold:roughness=1e-5") == "gold"


def test_materials_document_refuses_a_spec_the_parser_refuses():
    def doc(spec):
        return {"regions": [{"index": 0, "material": "gold", "spec": spec, "confidence": 0.9}]}

    assert materials_document_problem(doc("gold:roughness=0.2")) is None
    assert materials_document_problem(doc(None)) is None
    assert materials_document_problem(doc("nami-shibuichi:Ag=1e308,Cu=1e308")) is None
    problem = materials_document_problem(doc("gold:roughness=1e-320"))
    assert problem is not None and problem.startswith("regions[0].spec must be a material spec kogei accepts")
    assert materials_document_problem(doc("gold:Au=nan")) is not None

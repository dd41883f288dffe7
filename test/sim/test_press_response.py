"""A press that thins the sheet (``material.response: thinning``, issue 37 item 1).

A volume conductor (the hydrogel skin) loses sheet conductance where a press thins it; a
piezoresistive sheet gains it. The simulator, so the physics prior's simulated presses, and
the images follow the patch's choice; anything else is refused naming the key.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.material import Material
from eit_skin.patch.model import PatchError
from eit_skin.sim.drift import NO_DRIFT
from eit_skin.sim.scenario import Scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Push
from test.support.patch_copies import small_disc_data

SCALE_PA = 3e4


def patch_of(response: str | None):
    data = small_disc_data()
    if response is not None:
        data["layers"][0]["material"]["response"] = response
    return patch_from_dict(data)


def test_thinning_halves_the_conductance_at_the_pressure_scale_and_inverts_exactly():
    thin = Material("pressure", 1e-3, pressure_scale_pa=SCALE_PA, response="thinning")
    p = np.array([0.0, 0.1, 1.0, 10.0]) * SCALE_PA
    np.testing.assert_allclose(thin.conductance(p) / 1e-3, 1 / (1 + p / SCALE_PA), rtol=1e-15)
    assert thin.conductance(SCALE_PA) == pytest.approx(0.5e-3)
    np.testing.assert_allclose(thin.to_physical(thin.from_physical(p)), p, rtol=1e-12)
    # small loads: a linear-elastic sheet, t0 (1 - p / scale)
    assert thin.from_physical(1e-4 * SCALE_PA) == pytest.approx(-1e-4, rel=1e-3)
    assert thin.linear_pascals == 0.0 and thin.physical_range[0] < 0 < thin.physical_range[1]


def test_the_default_stays_piezoresistive_and_keeps_its_hash():
    assert patch_of(None).content_hash == patch_of("piezoresistive").content_hash
    assert patch_of("thinning").content_hash != patch_of(None).content_hash
    assert patch_of(None).layers[0].material.response == "piezoresistive"


@pytest.mark.parametrize(
    ("material", "message"),
    [
        ({"response": "squishy"}, r"material\.response: .*piezoresistive"),
        (
            {"quantity": "stretch", "gauge_factor": 2.0, "response": "thinning"},
            r"material\.response: only for quantity: pressure",
        ),
    ],
)
def test_a_response_that_cannot_be_honoured_is_refused(material, message):
    data = small_disc_data()
    mat = data["layers"][0]["material"]
    mat.update(material)
    if mat["quantity"] == "stretch":
        del mat["pressure_scale"]
    with pytest.raises(PatchError, match=rf"layers\[0\]\.{message}"):
        patch_from_dict(copy.deepcopy(data))


@pytest.fixture(scope="module")
def pressed():
    """(piezoresistive, thinning): fields and frames of one 5 N press at (10, 5) mm."""
    scenario = Scenario("press", (Push(0.1, 0.8, (0.01, 0.005), 5.0, 0.006, 0.1),), 1.0)
    out = []
    for response in ("piezoresistive", "thinning"):
        sim = SkinSimulator(patch_of(response), scenario, rate_hz=2.0, seed=1, drift=NO_DRIFT)
        base_sigma, sigma = sim.fields("pressure", 0.5)
        change = sim.frame(1)["pressure"].voltages_v - sim.reference("pressure")
        out.append((base_sigma, sigma, change))
    return out


def test_a_thinning_press_lowers_the_conductance_a_piezoresistive_one_raises_it(pressed):
    (base_r, sigma_r, dv_r), (base_t, sigma_t, dv_t) = pressed
    under = sigma_r != base_r  # the press's footprint
    assert under.any() and np.array_equal(under, sigma_t != base_t)
    assert np.all(sigma_t[under] < base_t[under]) and np.all(sigma_r[under] > base_r[under])
    # the same load, opposite conductance changes: the frames move the other way
    assert np.corrcoef(dv_r, dv_t)[0, 1] < -0.9

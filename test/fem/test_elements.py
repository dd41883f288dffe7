"""A tank's third dimension (eit_skin/fem/elements.py through ForwardModel's ``depth``).

Exact relations: with full-height electrodes the tank's field is the sheet's (z-invariant),
so voltages and Jacobian equal the 2-D model's to round-off; the Jacobian and the contact
Jacobian against central differences of the tank's own voltages; the 2-D limit as the depth
shrinks to the electrode height; the grading of the layers.
"""

import numpy as np
import pytest

from eit_skin.fem.device_fit import fit_depth
from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.elements import TankDepth
from eit_skin.fem.forward import ForwardModel
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

R = 0.05  # disk radius, m
ADJ16 = build_protocol(ProtocolSpec(), 16)
Z = 1e-3  # contact impedance, ohm*m
H = 0.01  # electrode height, m


@pytest.fixture(scope="module")
def mesh():
    return disk_mesh(R, h_m=0.008)


@pytest.fixture(scope="module")
def sheet(mesh):
    return ForwardModel(mesh, ADJ16, Z, 1e-3)


@pytest.fixture(scope="module")
def sigma(mesh):
    return 1.0 + 0.5 * np.random.default_rng(3).random(mesh.n_triangles)


@pytest.mark.parametrize("depth", [H, 0.2])
def test_full_height_electrodes_give_the_sheet(mesh, sheet, sigma, depth):
    tank = ForwardModel(mesh, ADJ16, Z, 1e-3, depth=TankDepth(depth, depth, 7.0))
    v2, v3 = sheet.voltages(sigma), tank.voltages(sigma)
    assert np.abs(v3 - v2).max() <= 1e-9 * np.abs(v2).max()
    j2, j3 = sheet.jacobian(sigma), tank.jacobian(sigma)
    assert np.abs(j3 - j2).max() <= 1e-9 * np.abs(j2).max()
    c2, c3 = sheet.contact_jacobian(sigma), tank.contact_jacobian(sigma)
    assert np.abs(c3 - c2).max() <= 1e-8 * np.abs(c2).max()


@pytest.fixture(scope="module")
def tall(mesh):
    return ForwardModel(mesh, ADJ16, Z, 1e-3, depth=TankDepth(0.2, H, 1.2))


def test_tall_tank_differs_from_the_sheet(sheet, tall, sigma):
    v2, v3 = sheet.voltages(sigma), tall.voltages(sigma)
    assert np.abs(v3 - v2).max() > 0.05 * np.abs(v2).max()
    sol = tall.solve(sigma)  # Kirchhoff: the injected current and nothing else
    np.testing.assert_allclose(sol.electrode_currents.sum(axis=1), 0, atol=1e-15)
    np.testing.assert_allclose(np.abs(sol.electrode_currents).max(axis=1), 1e-3, rtol=1e-9)
    assert sol.node_potentials.shape == (16, tall.mesh.n_nodes)  # the ring's plane


def test_tank_jacobian_is_the_derivative_of_its_voltages(mesh, tall, sigma):
    d = 1e-4 * np.random.default_rng(4).standard_normal(mesh.n_triangles)
    fd = (tall.voltages(sigma + d) - tall.voltages(sigma - d)) / 2
    J = tall.jacobian(sigma)
    assert np.linalg.norm(fd - J @ d) <= 1e-6 * np.linalg.norm(fd)
    basis = tall.jacobian_basis(sigma)
    np.testing.assert_allclose(basis.combination @ basis.products, J, atol=1e-12 * np.abs(J).max())


def test_tank_contact_jacobian_is_the_derivative_of_its_voltages(mesh, tall, sigma):
    depth = TankDepth(0.2, H, 1.2)
    step = 1e-4
    up = ForwardModel(mesh, ADJ16, Z * (1 + step), 1e-3, depth=depth).voltages(sigma)
    down = ForwardModel(mesh, ADJ16, Z * (1 - step), 1e-3, depth=depth).voltages(sigma)
    fd = (up - down) / (2 * step * Z)
    dz = tall.contact_jacobian(sigma).sum(axis=1)
    assert np.linalg.norm(fd - dz) <= 1e-5 * np.linalg.norm(fd)


def test_the_two_d_limit_as_the_depth_shrinks_to_the_electrode_height(mesh, sheet, sigma):
    v2 = sheet.voltages(sigma)
    gaps = [
        np.abs(
            ForwardModel(mesh, ADJ16, Z, 1e-3, depth=TankDepth(H * (1 + e), H, 1.0)).voltages(sigma)
            - v2
        ).max()
        for e in (0.5, 0.1, 0.01)
    ]
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 0.05 * gaps[0]  # about linear in the extra depth (50 x less: 35 x)


def test_levels_are_graded_from_the_ring():
    z = TankDepth(0.4, 0.01).levels()
    np.testing.assert_allclose(z[:3], [0, 0.0025, 0.005])
    assert z[-1] == pytest.approx(0.2)
    steps = np.diff(z)
    assert np.all(steps[3:-1] > steps[2:-2])  # growing away from the ring
    assert len(z) - 1 <= 12


@pytest.mark.parametrize(
    ("depth", "height", "outside", "field"),
    [(0.0, 0.01, 1.0, "depth"), (0.01, 0.02, 1.0, "electrode height"), (0.1, 0.01, 0, "outside")],
)
def test_bad_depth_is_refused_naming_the_field(depth, height, outside, field):
    with pytest.raises(ValueError, match=field):
        TankDepth(depth, height, outside)


@pytest.fixture(scope="module")
def coarse():
    return disk_mesh(R, electrode_width_rad=0.2, h_m=0.012)  # 10 mm electrodes


@pytest.mark.parametrize("depth", [0.06])
def test_fit_depth_finds_the_tank_of_a_no_load_frame(coarse, depth):
    """A no-load frame of a tank (or a sheet) plus 0.1 % noise: its depth comes back."""
    tank = None if depth is None else TankDepth(depth, H, 2.0)
    frame = ForwardModel(coarse, ADJ16, 5e-3, 1e-3, depth=tank).voltages(2.0)
    frame = frame * (1 + 1e-3 * np.random.default_rng(5).standard_normal(frame.size))
    start = {"sheet_conductance_s": 1.0, "contact_impedance_ohm_m": Z, "current_a": 1e-3}
    fitted, fit = fit_depth(coarse, ADJ16, frame, H, **start)
    if depth is None:
        assert fitted is None or fitted < 1.5 * H
    else:
        assert fitted == pytest.approx(depth, rel=0.1)
    assert fit.residual < 3e-3


def test_local_update_of_a_tank_equals_its_direct_solve(mesh, tall):
    """The simulator's Woodbury update (the changed columns' slab nodes) on a tank."""
    from eit_skin.fem.forward_update import LocalForwardUpdate

    base = np.full(mesh.n_triangles, 1.2)
    update = LocalForwardUpdate(tall, base)
    press = base.copy()
    press[np.linalg.norm(mesh.centroids - [0.02, 0.01], axis=1) < 0.008] = 3.0
    np.testing.assert_allclose(update.voltages(press), tall.voltages(press), rtol=1e-9, atol=0)
    assert update.update_solves == 1

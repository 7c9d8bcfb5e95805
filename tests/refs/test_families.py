"""Each trajectory family against its definition."""

import math

import pytest
import torch

from datt.errors import ConfigError
from datt.refs import ChainedPoly, CsvReference, Fixed, Mixed, Poly, Polygon, Zigzag, load_csv_reference
from datt.refs.base import piecewise_linear
from datt.refs.poly import eval_pieces

DT = 0.02
T_GRID = torch.arange(528, dtype=torch.float32) * DT  # 500 steps + lookahead, as the env uses
T64 = torch.arange(528, dtype=torch.float64) * DT


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


@pytest.mark.parametrize("alternate", [False, True])
def test_zigzag_knots_bounds_and_piecewise_linear(alternate):
    fam = Zigzag(alternate_sign=alternate)
    knot_t, knot_p = fam.sample_knots(64, float(T64[-1]), gen(), T64)
    seg = knot_t.diff(dim=1)
    assert seg.min() >= 0.5 and seg.max() <= 1.5
    assert knot_t[:, -1].min() >= T64[-1]  # covers the whole table
    assert knot_p[:, 0].abs().max() == 0 and knot_p.abs().max() <= 1.0
    if alternate:
        signs = torch.sign(knot_p[:, 1:, 0])
        assert (signs[:, 1:] * signs[:, :-1] <= 0).all()
    table = fam.sample(64, T64, gen())
    assert table.shape == (64, 528, 3) and table[..., 2].abs().max() == 0
    assert torch.allclose(table[..., :2], piecewise_linear(knot_t, knot_p, T64))
    # piecewise linear: second differences vanish except at steps next to a knot
    d2 = table[:, 2:, :2] - 2 * table[:, 1:-1, :2] + table[:, :-2, :2]
    t_mid = T64[1:-1]
    near_knot = ((t_mid[None, :, None] - knot_t[:, None, :]).abs() < DT + 1e-9).any(-1)
    assert d2[~near_knot].abs().max() < 1e-9
    assert d2[near_knot].abs().max() > 1e-3  # and it really turns at knots


def test_zigzag_mean_speed_is_infeasible_scale():
    table = Zigzag().sample(256, T_GRID, gen())
    speed = (table.diff(dim=1).norm(dim=-1) / DT).mean()
    assert 0.7 < speed < 1.5


def test_poly_degree_five_through_origin():
    fam = Poly(vel_max_mps=1.0, acc_max_mps2=1.0, max_amplitude_m=1.5)
    knot_t, coeffs = fam.sample_pieces(128, gen(), T64)
    assert coeffs.shape == (128, 1, 6, 2)
    ends = torch.tensor([0.0, 10.0], dtype=torch.float64)
    assert eval_pieces(knot_t, coeffs, ends).abs().max() < 1e-9
    table = fam.sample(128, T_GRID, gen())
    assert table[:, 0].abs().max() < 1e-6 and table[:, 500].abs().max() < 1e-5
    assert table[:, 500:].abs().max() < 1e-5  # holds the origin after the episode
    assert table.abs().max() <= 1.5 + 1e-4  # peak found on a 5 ms grid
    # a quintic: sixth finite differences vanish inside the episode
    x = fam.sample(4, T64, gen())[:, :500, :2]
    d6 = x
    for _ in range(6):
        d6 = d6.diff(dim=1)
    assert d6.abs().max() < 1e-12


def test_poly_boundary_derivatives_are_the_sampled_ones():
    fam = Poly(max_amplitude_m=1e9)  # no rescaling
    g = gen(5)
    knot_t, coeffs = fam.sample_pieces(16, g, T64)
    g = gen(5)
    v = fam._uniform((16, 2, 2), -1.0, 1.0, g, T64)
    a = fam._uniform((16, 2, 2), -1.0, 1.0, g, T64)
    ends = torch.tensor([0.0, 10.0], dtype=torch.float64)
    assert torch.allclose(eval_pieces(knot_t, coeffs, ends, derivative=1), v, atol=1e-9)
    assert torch.allclose(eval_pieces(knot_t, coeffs, ends, derivative=2), a, atol=1e-9)


def test_chained_poly_nodes_at_origin_and_c3_continuous():
    fam = ChainedPoly()
    knot_t, coeffs = fam.sample_pieces(32, 10.54, gen(), T64)
    h = knot_t.diff(dim=1)
    assert h.min() >= 1.5 and h.max() <= 4.0
    n, m = h.shape
    for order in range(4):
        # left limit: piece k-1 at its end; right limit: piece k at its start
        left = torch.zeros(n, m - 1, 2, dtype=torch.float64)
        right = torch.zeros(n, m - 1, 2, dtype=torch.float64)
        for i in range(order, 6):
            f = math.factorial(i) // math.factorial(i - order)
            left += f * coeffs[:, :-1, i] * h[:, :-1, None] ** (i - order)
        right = math.factorial(order) * coeffs[:, 1:, order]
        scale = 1.0 + right.abs().max()
        assert (left - right).abs().max() / scale < 1e-8, f"derivative {order} jumps"
        if order == 0:
            assert right.abs().max() < 1e-12  # nodes at the origin
    # starts at rest at the origin
    start = eval_pieces(knot_t, coeffs, torch.zeros(1, dtype=torch.float64), derivative=1)
    assert start.abs().max() < 1e-12
    table = fam.sample(32, T_GRID, gen())
    assert table[:, 0].abs().max() < 1e-6 and table.abs().max() < 3.0


def test_star_geometry_speed_and_lead_in():
    star = Polygon(
        points_min=5,
        points_max=5,
        step=2,
        radius_m=0.7,
        speed_min_mps=1.0,
        speed_max_mps=1.0,
        through_origin=False,
        lead_in_s=1.0,
        random_rotation=False,
    )
    table = star.sample(2, T64, gen())
    assert torch.equal(table[0], table[1])  # deterministic
    assert table[0, 0].abs().max() == 0
    first_vertex = table[0, 50]  # after the 1 s lead-in
    assert first_vertex[:2].norm().item() == pytest.approx(0.7, abs=1e-9)
    assert first_vertex[0].item() == pytest.approx(0.0, abs=1e-9)  # phase 90°: on +y
    speed = table[0, 51:].diff(dim=0).norm(dim=-1) / DT
    assert speed.max().item() == pytest.approx(1.0, abs=1e-6)
    assert speed.median().item() == pytest.approx(1.0, abs=1e-6)
    r = table[0, 50:, :2].norm(dim=-1)
    assert r.max() <= 0.7 + 1e-9 and r.min() < 0.7 * math.cos(2 * math.pi / 5) + 0.02  # chords cut inside


def test_polygon_passes_through_origin_with_regular_sides():
    fam = Polygon()
    table = fam.sample(64, T64, gen())
    assert table[:, 0].abs().max() < 1e-12
    r = (table[:, :, :2] - table[:, :, :2].mean(1, keepdim=True)).norm(dim=-1)
    assert r.max() < 1.0
    step = table.diff(dim=1).norm(dim=-1) / DT
    assert step.max() <= 1.6 + 1e-6


def test_fixed_is_identical_for_all_drones_and_ignores_env_generator():
    fam = Fixed(Zigzag(), seed=7)
    a = fam.sample(5, T_GRID, gen(0))
    b = fam.sample(3, T_GRID, gen(99))
    assert torch.equal(a[0], a[4]) and torch.equal(a[0], b[0])
    assert not torch.equal(a[0], Fixed(Zigzag(), seed=8).sample(1, T_GRID, gen(0))[0])


def test_mixed_draws_per_drone_with_weights():
    fams = {"zigzag": Zigzag(), "poly": Poly()}
    only_poly = Mixed(fams, weights={"zigzag": 0.0, "poly": 1.0}).sample(16, T64, gen())
    x = only_poly[:, :500, :2]
    for _ in range(6):
        x = x.diff(dim=1)
    assert x.abs().max() < 1e-12  # all quintics
    both = Mixed(fams).sample(400, T64, gen())
    d2 = (both[:, 2:500] - 2 * both[:, 1:499] + both[:, :498]).abs()
    is_zigzag = (d2 < 1e-12).float().mean(dim=(1, 2)) > 0.8
    assert 0.35 < is_zigzag.float().mean() < 0.65
    with pytest.raises(ValueError, match="traj.weights"):
        Mixed(fams, weights={"nope": 1.0})


def write_csv(path, rows, header="t,x,y,z"):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


def test_csv_round_trip(tmp_path):
    rows = [(0.0, 0.0, 0.0, 0.0), (0.5, 1.0, 0.0, 0.2), (1.0, 1.0, 1.0, 0.4), (2.0, -1.0, 0.5, 0.0)]
    path = write_csv(tmp_path / "ref.csv", rows)
    t, pos = load_csv_reference(path)
    assert t.tolist() == [0.0, 0.5, 1.0, 2.0]
    fam = CsvReference(str(path))
    table = fam.sample(3, T64, gen())
    for ti, x, y, z in rows:
        k = round(ti / DT)
        assert table[0, k].tolist() == pytest.approx([x, y, z], abs=1e-12)
    assert table[2, 25].tolist() == pytest.approx([1.0, 0.0, 0.2])  # t = 0.5
    assert table[0, 12].tolist() == pytest.approx([0.48, 0.0, 0.096])  # interpolated at 0.24 s
    assert torch.allclose(table[0, 150], torch.tensor([-1.0, 0.5, 0.0], dtype=torch.float64))  # holds the end
    looped = CsvReference(str(path), loop=True).sample(1, T64, gen())
    assert torch.allclose(looped[0, 100 + 25], table[0, 25])
    rel = CsvReference(str(path), relative=True, time_scale=2.0).sample(1, T64, gen())
    assert rel[0, 50].tolist() == pytest.approx([1.0, 0.0, 0.2])  # 0.5 s stretched to 1.0 s


@pytest.mark.parametrize(
    "content, message",
    [
        ("t,x,y\n0,0,0\n1,1,1\n", "missing column(s) z"),
        ("t,x,y,z\n0,0,0,0\n1,nan,1,0\n", "line 3: NaN"),
        ("t,x,y,z\n0,0,0,0\n1,1,1,0\n0.5,1,1,0\n", "line 4: time must strictly increase"),
        ("t,x,y,z\n0,0,0,0\n", "at least 2 data rows"),
        ("t,x,y,z\n0,0,0,0\n1,a,1,0\n", "non-numeric"),
    ],
)
def test_csv_errors_are_one_line_and_name_the_key(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(ConfigError) as info:
        CsvReference(str(path))
    text = str(info.value)
    assert text.startswith("traj.path:") and message in text and "\n" not in text


def test_csv_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"traj.path: file .*nope.csv' not found"):
        CsvReference(str(tmp_path / "nope.csv"))


@pytest.mark.parametrize("family", [Zigzag, Poly, ChainedPoly, Polygon])
def test_seeded_reproducibility(family):
    fam = family()
    assert torch.equal(fam.sample(4, T_GRID, gen(1)), fam.sample(4, T_GRID, gen(1)))
    assert not torch.equal(fam.sample(4, T_GRID, gen(1)), fam.sample(4, T_GRID, gen(2)))


def test_zigzag_segment_durations_follow_their_uniform_law():
    """Segments are U(seg_min_s, seg_max_s): over many draws min, max and mean match the law
    (a narrower range, e.g. U(0.5, 1.0) for U(0.5, 1.5), moves the mean by 0.25 s)."""
    from datt.refs import Zigzag

    gen = torch.Generator().manual_seed(0)
    knot_t, _ = Zigzag(seg_min_s=0.5, seg_max_s=1.5).sample_knots(2000, 10.0, gen, torch.zeros(1, dtype=torch.float64))
    seg = knot_t.diff(dim=1).flatten()
    assert seg.min() >= 0.5 and seg.max() <= 1.5
    assert seg.min() < 0.51 and seg.max() > 1.49
    assert seg.mean().item() == pytest.approx(1.0, abs=0.01)

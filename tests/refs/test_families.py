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
# the authors' evaluation star as conf/traj/star.yaml sets it
STAR = dict(
    points_min=5,
    points_max=5,
    step=2,
    radius_m=0.7,
    through_origin=False,
    lead_in_s=1.0,
    speed_min_mps=1.0,
    speed_max_mps=1.0,
    phase_deg=0.0,
    random_rotation=False,
)


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


@pytest.mark.parametrize("waypoints", ["iid", "alternating"])
def test_zigzag_knots_bounds_and_piecewise_linear(waypoints):
    fam = Zigzag(seg_min_s=0.5, seg_max_s=1.5, waypoints=waypoints)
    knot_t, knot_p = fam.sample_knots(64, float(T64[-1]), gen(), T64)
    seg = knot_t.diff(dim=1)
    assert seg.min() >= 0.5 and seg.max() <= 1.5
    assert knot_t[:, -1].min() >= T64[-1]  # covers the whole table
    assert knot_p[:, 0].abs().max() == 0 and knot_p.abs().max() <= 1.0
    if waypoints == "alternating":
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


def _mean_speed_mps(name, count=1000):
    """Time average of ‖ṗ‖ over the 10 s episode, over ``count`` draws of ``conf/traj/<name>``."""
    from datt.configuration import compose, instantiate_option

    family = instantiate_option(compose("train", [f"traj={name}"]), "traj")
    table = family.sample(count, T64[:501], gen(3))
    return (table.diff(dim=1).norm(dim=-1) / DT).mean().item()


@pytest.mark.parametrize(
    "name, speed_mps",
    # the docstrings' figures: the authors' generator, the paper's stated ≈ 2 m/s, the paper's text
    [
        ("zigzag", 1.32),
        ("zigzag_fast", 2.0),
        ("zigzag_iid", 1.0),
        ("star", 0.99),
        ("poly", 0.41),
        ("chained_poly", 0.72),
        ("polygon", 1.23),
        ("mixed", 0.82),
        ("train_mix", 1.08),
    ],
)
def test_reference_family_mean_speed(name, speed_mps):
    assert _mean_speed_mps(name) == pytest.approx(speed_mps, rel=0.03)


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
    fam = Poly(max_amplitude_m=1000.0)  # no rescaling
    g = gen(5)
    knot_t, coeffs = fam.sample_pieces(16, g, T64)
    g = gen(5)
    v = fam._uniform((16, 2, 2), -1.0, 1.0, g, T64)
    a = fam._uniform((16, 2, 2), -1.0, 1.0, g, T64)
    ends = torch.tensor([0.0, 10.0], dtype=torch.float64)
    assert torch.allclose(eval_pieces(knot_t, coeffs, ends, derivative=1), v, atol=1e-9)
    assert torch.allclose(eval_pieces(knot_t, coeffs, ends, derivative=2), a, atol=1e-9)


def test_chained_poly_nodes_at_origin_and_c3_continuous():
    fam = ChainedPoly()  # the paper's pieces: U(1.5, 4.0) s
    knot_t, coeffs = fam.sample_pieces(32, 10.54, gen(), T64)
    h = knot_t.diff(dim=1)
    assert h.min() >= 1.5 and h.max() <= 4.0 and h.min() < 1.6 and h.max() > 3.9
    assert h.shape[1] == math.ceil(10.54 / 1.5)
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
    star = Polygon(**STAR)
    table = star.sample(2, T64, gen())
    assert torch.equal(table[0], table[1])  # deterministic
    assert table[0, 0].abs().max() == 0
    first_vertex = table[0, 50]  # after the 1 s lead-in
    assert first_vertex[:2].norm().item() == pytest.approx(0.7, abs=1e-9)
    assert first_vertex[1].item() == pytest.approx(0.0, abs=1e-9)  # the authors' star: first vertex on +x
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


def test_mixed_weights_default_to_one_and_must_have_a_positive_sum():
    fams = {"zigzag": Zigzag(), "poly": Poly(), "star": Polygon(**STAR)}
    assert Mixed(fams).probs.tolist() == pytest.approx([1 / 3] * 3)
    assert Mixed(fams, weights={"zigzag": 4.0}).probs.tolist() == pytest.approx([4 / 6, 1 / 6, 1 / 6])
    for bad in ({"zigzag": 0.0, "poly": 0.0, "star": 0.0}, {"zigzag": -1.0}):
        with pytest.raises(ValueError) as info:
            Mixed(fams, weights=bad)
        assert str(info.value) == "traj.weights: must be >= 0 with a positive sum"
    with pytest.raises(ValueError) as info:
        Mixed({})
    assert str(info.value) == "traj.families: needs at least one family"


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
        ("t,x\n0,0\n1,1\n", "missing column(s) y, z"),
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


@pytest.mark.parametrize(
    "family",
    [Zigzag, lambda: Zigzag(waypoints="iid"), Poly, ChainedPoly, Polygon],
    ids=["zigzag", "zigzag_iid", "poly", "chained_poly", "polygon"],
)
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


@pytest.mark.parametrize("duration_s", [0.02, 0.3, 0.59, 0.61, 1.2, 10.0])
def test_zigzag_knots_cover_any_duration(duration_s):
    """However short or long the reference, its knots reach past its end (no held tail)."""
    gen = torch.Generator().manual_seed(1)
    knot_t, knot_p = Zigzag().sample_knots(500, duration_s, gen, torch.zeros(1, dtype=torch.float64))
    assert knot_t.shape[1] >= 3 and knot_p.shape[:2] == knot_t.shape
    assert (knot_t[:, -1] >= duration_s).all()


CSV_ROWS = [(0.0, 0.0, 0.0, 0.0), (0.5, 1.0, 0.0, 0.2), (1.0, 1.0, 1.0, 0.4), (2.0, -1.0, 0.5, 0.0)]


@pytest.mark.parametrize(
    "sep, encoding", [(",", "utf-8"), (";", "utf-8"), ("\t", "utf-8"), (",", "utf-8-sig"), (";", "utf-8-sig")]
)
def test_csv_separators_and_bom(tmp_path, sep, encoding):
    """Spreadsheets write ';' or tabs, and Excel a UTF-8 BOM: the same file in each form reads the same."""
    text = sep.join("txyz") + "\n" + "\n".join(sep.join(str(v) for v in r) for r in CSV_ROWS) + "\n"
    path = tmp_path / "ref.csv"
    path.write_text(text, encoding=encoding)
    t, pos = load_csv_reference(path)
    assert t.tolist() == [0.0, 0.5, 1.0, 2.0]
    assert pos.tolist() == [list(r[1:]) for r in CSV_ROWS]


def test_csv_times_start_at_zero_and_loop_on_the_last_time(tmp_path):
    shifted = [(t + 3.0, x, y, z) for t, x, y, z in CSV_ROWS]
    t, _ = load_csv_reference(write_csv(tmp_path / "ref.csv", shifted))
    assert t.tolist() == [0.0, 0.5, 1.0, 2.0]
    fam = CsvReference(str(tmp_path / "ref.csv"), loop=True)
    table = fam.sample(1, T64, gen())
    assert table.dtype == torch.float64 and table.shape == (1, len(T64), 3)
    assert torch.allclose(table[0, 100 + 25], table[0, 25]) and torch.allclose(table[0, 100 + 75], table[0, 75])
    f32 = fam.sample(2, T64.float(), gen())
    assert f32.dtype == torch.float32 and f32.shape == (2, len(T64), 3)


def test_csv_relative_moves_the_start_to_the_origin(tmp_path):
    rows = [(t, x + 5.0, y - 2.0, z + 1.0) for t, x, y, z in CSV_ROWS]
    path = write_csv(tmp_path / "ref.csv", rows)
    rel = CsvReference(str(path), relative=True).sample(1, T64, gen())
    plain = CsvReference(str(path)).sample(1, T64, gen())
    assert rel[0, 0].tolist() == [0.0, 0.0, 0.0]
    assert torch.allclose(rel, plain - torch.tensor([5.0, -2.0, 1.0], dtype=torch.float64))


@pytest.mark.parametrize(
    "content, message",
    [
        (
            "t;x;y;z\n0;0;0;0\n1;0,5;0;0\n",
            "traj.path: bad.csv line 3: non-numeric value in t,x,y,z (decimal commas? use '.' for decimals)",
        ),
        ("t,x,y,z\n0,0,0,0\n1,a,0,0\n", "traj.path: bad.csv line 3: non-numeric value in t,x,y,z"),
        (
            "t;x;y\n0;0;0\n1;1;1\n",
            "traj.path: bad.csv is missing column(s) z; required: t, x, y, z "
            "(header read as ['t', 'x', 'y'] with separator ';')",
        ),
        (
            "t,x,y,z\n0,0,0,0\n1,1,1,0\n1,2,1,0\n",
            "traj.path: bad.csv line 4: time must strictly increase (t=1.0 after 1.0)",
        ),
    ],
)
def test_csv_error_messages(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(ConfigError) as info:
        load_csv_reference(path)
    assert str(info.value) == message


def test_csv_not_utf8(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"t,x,y,z\n" + b"0,0,0,0\n" * 5000 + b"1,0,0,\xff\n")  # far past the first read
    with pytest.raises(
        ConfigError, match=r"^traj.path: bad.csv is not UTF-8 text \(byte 40014\); save it as UTF-8 CSV$"
    ):
        load_csv_reference(path)


def test_csv_extent_limit(tmp_path):
    rows = [(0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (2.0, 3.0, -4.0, 0.0), (3.0, 0.0, 0.0, 0.0)]
    path = write_csv(tmp_path / "ref.csv", rows)
    CsvReference(str(path), max_abs_m=4.0)  # exactly at the limit is allowed
    with pytest.raises(ConfigError) as info:
        CsvReference(str(path), max_abs_m=3.5)
    assert str(info.value) == (
        "traj.max_abs_m: ref.csv line 4 is 4 m from the origin, beyond 3.5 m (positions are metres; use "
        "relative=true for a far-away frame, or raise traj.max_abs_m)"
    )
    small = write_csv(tmp_path / "small.csv", [(0.0, 0.0, 0.0, 0.0), (1.0, 0.2, 0.0, 0.0)])
    assert CsvReference(str(small), max_abs_m=0.5).pos_m.abs().max() == pytest.approx(0.2)  # a limit under 1 m works
    with pytest.raises(ConfigError, match=r"^traj.max_abs_m: must be a finite number in \(0, 10000\], got 0.0$"):
        CsvReference(str(small), max_abs_m=0.0)
    with pytest.raises(ConfigError, match=r"^traj.time_scale: must be a finite number in \(0, 100\], got 0.0$"):
        CsvReference(str(small), time_scale=0.0)
    assert CsvReference(str(small)).path == str(small) and not CsvReference(str(small)).loop


def test_csv_relative_path_is_relative_to_the_working_directory(tmp_path, monkeypatch):
    write_csv(tmp_path / "ref.csv", CSV_ROWS)
    monkeypatch.chdir(tmp_path)
    t, _ = load_csv_reference("ref.csv")
    assert len(t) == 4


def test_chained_poly_knots_cover_the_episode_and_velocities_are_symmetric():
    fam = ChainedPoly(piece_min_s=1.5, piece_max_s=4.0, knot_vel_max_mps=1.5)
    knot_t, coeffs = fam.sample_pieces(4000, 10.0, gen(3), torch.zeros((), dtype=torch.float64))
    assert knot_t.shape[1] - 1 == math.ceil(10.0 / 1.5)  # enough pieces even if every gap is the shortest
    assert (knot_t[:, -1] >= 10.0).all()
    # node velocity = p'(knot) = coefficient c1 of each piece: U(-1.5, 1.5), 0 at the first node
    v = coeffs[:, :, 1]
    assert v[:, 0].abs().max() < 1e-12
    inner = v[:, 1:].reshape(-1)
    assert inner.min() < -1.4 and inner.max() > 1.4 and inner.abs().max() <= 1.5 + 1e-12
    assert abs(inner.mean()) < 0.02


def test_poly_peak_is_found_on_a_fine_grid_in_float64():
    """The amplitude cap: the largest |x| or |y| over the whole episode equals max_amplitude_m
    for every sample that reached it (measured on a 10x finer grid than the cap's own)."""
    fam = Poly(duration_s=10.0, vel_max_mps=3.0, acc_max_mps2=3.0, max_amplitude_m=0.4)
    like = torch.zeros((), dtype=torch.float64)
    knot_t, coeffs = fam.sample_pieces(64, gen(4), like)
    assert knot_t.dtype == torch.float64 and coeffs.dtype == torch.float64
    fine = torch.linspace(0, 10.0, 20001, dtype=torch.float64)
    peak = eval_pieces(knot_t, coeffs, fine).abs().amax(dim=(1, 2))
    assert torch.allclose(peak, torch.full_like(peak, 0.4), atol=1e-6)
    table = fam.sample(3, T64.float(), gen(4))
    assert table.dtype == torch.float32


def test_poly_cap_is_exact_on_its_own_grid():
    """The cap is measured on 2001 float64 points of [0, duration_s]: on that grid every capped
    draw peaks at exactly max_amplitude_m, the others below it (amplitudes under 1 m too)."""
    fam = Poly(duration_s=2.0, vel_max_mps=0.5, acc_max_mps2=0.5, max_amplitude_m=0.15)
    knot_t, coeffs = fam.sample_pieces(200, gen(6), torch.zeros((), dtype=torch.float64))
    unscaled = Poly(duration_s=2.0, vel_max_mps=0.5, acc_max_mps2=0.5, max_amplitude_m=1000.0)
    _, raw = unscaled.sample_pieces(200, gen(6), torch.zeros((), dtype=torch.float64))
    grid = torch.linspace(0, 2.0, 2001, dtype=torch.float64)
    peak = eval_pieces(knot_t, coeffs, grid).abs().amax(dim=(1, 2))
    raw_peak = eval_pieces(knot_t, raw, grid).abs().amax(dim=(1, 2))
    capped = raw_peak > 0.15
    assert 10 < capped.sum() < 190 and raw_peak.max() < 1
    assert torch.equal(coeffs[~capped], raw[~capped])
    assert torch.allclose(peak[capped], torch.full_like(peak[capped], 0.15), rtol=0, atol=1e-15)


def test_mixed_draws_only_from_its_generator():
    """The family choice and every member's draw use the generator passed in: the global RNG
    state does not change the references."""
    fam = Mixed({"zigzag": Zigzag(), "poly": Poly()}, weights={"zigzag": 0.5, "poly": 0.5})
    torch.manual_seed(1)
    a = fam.sample(16, T_GRID, gen(9))
    torch.manual_seed(2)
    b = fam.sample(16, T_GRID, gen(9))
    assert torch.equal(a, b)


def test_piecewise_linear_by_hand():
    knot_t = torch.tensor([[0.0, 1.0, 3.0], [0.0, 2.0, 2.0]], dtype=torch.float64)  # drone 1: a repeated knot
    knot_p = torch.tensor(
        [[[0.0, 1.0], [2.0, 1.0], [-2.0, 3.0]], [[1.0, 0.0], [3.0, 0.0], [5.0, 0.0]]], dtype=torch.float64
    )
    t = torch.tensor([-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 4.0], dtype=torch.float64)
    out = piecewise_linear(knot_t, knot_p, t)
    assert out.shape == (2, 7, 2)
    assert out[0, :, 0].tolist() == [0.0, 0.0, 1.0, 2.0, 0.0, -2.0, -2.0]  # holds both ends
    assert out[0, :, 1].tolist() == [1.0, 1.0, 1.0, 1.0, 2.0, 3.0, 3.0]
    # at a repeated knot the earlier value holds at that instant, the later one after it
    assert torch.isfinite(out).all() and out[1, :, 0].tolist() == [1.0, 1.0, 1.5, 2.0, 3.0, 5.0, 5.0]
    f32 = piecewise_linear(knot_t, knot_p, t.float())
    assert f32.dtype == torch.float64 and torch.equal(f32, out)  # computed in the knots' dtype
    for bad in (knot_p[:, :2], knot_p[:1]):  # a knot without a value, a drone without knots
        with pytest.raises(ValueError) as info:
            piecewise_linear(knot_t, bad, t)
        assert str(info.value) == f"piecewise_linear: knot times (2, 3) and values {tuple(bad.shape)} disagree"


@pytest.mark.parametrize("through_origin", [True, False], ids=["through_origin", "lead_in"])
def test_polygon_visits_its_vertices_at_their_times(through_origin):
    """A triangle at 1 m/s from a known phase: between two vertices the reference is their chord
    at constant speed; the centred shape starts at the origin and reaches the first vertex after
    lead_in_s (0.1 s: not a float32 number, so float64 tables must not round it). The table has
    the dtype of the time grid."""
    r, lead = 0.5, 0.1
    triangle = dict(points_min=3, points_max=3, step=1, radius_m=r, phase_deg=90.0, lead_in_s=lead)
    fam = Polygon(**{**STAR, **triangle, "through_origin": through_origin})  # at 1 m/s, not rotated
    ang = [math.pi / 2 + 2 * math.pi * i / 3 for i in range(4)]
    vertex = torch.tensor([[r * math.cos(a), r * math.sin(a)] for a in ang], dtype=torch.float64)
    side = 2 * r * math.sin(math.pi / 3)
    start = 0.0 if through_origin else lead
    if through_origin:
        vertex = vertex - vertex[0]
    t = torch.tensor([start + side * (k + f) for k in range(3) for f in (0.0, 0.25, 0.5)], dtype=torch.float64)
    want = torch.stack([vertex[k] + f * (vertex[k + 1] - vertex[k]) for k in range(3) for f in (0.0, 0.25, 0.5)])
    got = fam.sample(2, t, gen())
    assert got.dtype == torch.float64 and got.shape == (2, 9, 3)
    assert torch.allclose(got[..., :2], want.expand(2, -1, -1), rtol=0, atol=1e-12) and got[..., 2].abs().max() == 0
    if not through_origin:
        mid_lead = fam.sample(1, torch.tensor([0.0, lead / 4], dtype=torch.float64), gen())[0, :, :2]
        want_lead = torch.stack((torch.zeros(2, dtype=torch.float64), vertex[0] / 4))
        assert torch.allclose(mid_lead, want_lead, rtol=0, atol=1e-12)
    assert fam.sample(2, t.float(), gen()).dtype == torch.float32


def test_zigzag_waypoint_laws():
    """Independent: each waypoint coordinate U(−r, r). Alternating (the authors'): waypoint k's
    coordinates U(0, r) for even k, U(−r, 0) for odd k, the first positive, per axis."""
    r = 0.8
    _, plain = Zigzag(range_m=r, waypoints="iid").sample_knots(4000, 10.0, gen(5), T64)
    wp = plain[:, 1:]
    assert wp.abs().max() <= r and wp.min() < -0.79 and wp.max() > 0.79 and wp.mean().abs() < 0.01
    assert (wp[:, :-1] * wp[:, 1:] > 0).double().mean() == pytest.approx(0.5, abs=0.02)  # signs independent
    _, alt = Zigzag(range_m=r).sample_knots(4000, 10.0, gen(5), T64)
    wp = alt[:, 1:]
    assert wp.abs().max() <= r and wp.abs().mean() == pytest.approx(r / 2, abs=0.01)
    assert (wp[:, 0::2] >= 0).all() and (wp[:, 1::2] <= 0).all()
    assert wp[:, 0::2].min() < 0.01 and wp[:, 0::2].max() > 0.79  # the whole of U(0, r)
    assert wp[:, 1::2].max() > -0.01 and wp[:, 1::2].min() < -0.79


def test_zigzag_defaults_are_the_authors_generator():
    """The constructor's defaults and ``traj=zigzag``: alternating, 0.6-1.5 s, ±1 m."""
    from datt.configuration import compose, instantiate_option

    for fam in (Zigzag(), instantiate_option(compose("train", ["traj=zigzag"]), "traj")):
        assert (fam.waypoints, fam.seg_min_s, fam.seg_max_s, fam.range_m) == ("alternating", 0.6, 1.5, 1.0)


def test_zigzag_unknown_waypoint_law_names_the_allowed_ones():
    with pytest.raises(ValueError, match=r"^traj.waypoints: unknown value 'uniform'; allowed: alternating, iid$"):
        Zigzag(waypoints="uniform")


@pytest.mark.parametrize(
    "family, kwargs, message",
    [
        (Zigzag, {"seg_min_s": 0.0}, "traj.seg_min_s: must be a finite number in (0, 3600], got 0.0"),
        (Zigzag, {"seg_min_s": 2.0}, "traj.seg_min_s/seg_max_s: need 0 < min <= max, got 2.0, 1.5"),
        (Zigzag, {"range_m": -0.1}, "traj.range_m: must be a finite number in [0, 20], got -0.1"),
        (Zigzag, {"waypoints": "uniform"}, "traj.waypoints: unknown value 'uniform'; allowed: alternating, iid"),
        (Polygon, {"points_min": 2}, "traj.points_min: must be an integer in [3, 1000], got 2"),
        (Polygon, {"points_min": 7}, "traj.points_min/points_max: need 3 <= min <= max, got 7, 6"),
        (Polygon, {"step": 0}, "traj.step: must be an integer in [1, 1000], got 0"),
        (Polygon, {"step": 2}, "traj.step: must be >= 1 and coprime with every point count, got 2"),
        (Polygon, {"radius_m": 0.0}, "traj.radius_m: must be a finite number in (0, 20], got 0.0"),
        (Polygon, {"speed_min_mps": 0.0}, "traj.speed_min_mps: must be a finite number in (0, 20], got 0.0"),
        (Polygon, {"speed_min_mps": 2.0}, "traj.speed_min_mps/speed_max_mps: need min <= max, got 2.0, 1.6"),
        (Polygon, {"lead_in_s": -1.0}, "traj.lead_in_s: must be a finite number in [0, 3600], got -1.0"),
        (Polygon, {"through_origin": 1}, "traj.through_origin: must be true or false, got 1"),
        (ChainedPoly, {"piece_min_s": 0.0}, "traj.piece_min_s: must be a finite number in (0, 3600], got 0.0"),
        (ChainedPoly, {"piece_min_s": 5.0}, "traj.piece_min_s/piece_max_s: need 0 < min <= max, got 5.0, 4.0"),
        (Poly, {"duration_s": 0.0}, "traj.duration_s: must be a finite number in (0, 3600], got 0.0"),
        (Poly, {"vel_max_mps": -1.0}, "traj.vel_max_mps: must be a finite number in [0, 20], got -1.0"),
        (Poly, {"acc_max_mps2": float("nan")}, "traj.acc_max_mps2: must be a finite number in [0, 200], got nan"),
        (Poly, {"max_amplitude_m": 0.0}, "traj.max_amplitude_m: must be a finite number in (0, 1000], got 0.0"),
        (Poly, {"degree": 4}, "traj.degree: unknown value 4; allowed: 3, 5, 7"),
        (Poly, {"jerk_max_mps3": -1.0}, "traj.jerk_max_mps3: must be a finite number in [0, 1000], got -1.0"),
    ],
)
def test_family_parameter_messages(family, kwargs, message):
    with pytest.raises(ValueError) as info:
        family(**kwargs)
    assert str(info.value).startswith(message)


def test_family_parameter_edges_are_allowed():
    Zigzag(seg_min_s=1.0, seg_max_s=1.0, range_m=0.0)
    Polygon(points_min=3, points_max=3, step=1, speed_min_mps=1.0, speed_max_mps=1.0, lead_in_s=0.0)
    ChainedPoly(piece_min_s=2.0, piece_max_s=2.0)
    Poly(vel_max_mps=0.0, acc_max_mps2=0.0)
    ChainedPoly(piece_min_s=0.01, piece_max_s=0.01)  # any positive lengths and durations
    Poly(duration_s=0.01)


def test_polygon_draws_and_timing():
    """Point counts U{3..6}, speeds U(0.9, 1.6), random rotation over the circle; a side of a
    {p} polygon of radius r is 2 r sin(π/p), flown at the drone's speed."""
    fam = Polygon()
    table = fam.sample(600, T64, gen(2))
    speed = (table.diff(dim=1).norm(dim=-1) / DT).amax(1)
    assert speed.min() > 0.9 - 1e-6 and speed.max() < 1.6 + 1e-6 and speed.min() < 0.95 and speed.max() > 1.55
    first_dir = torch.atan2(table[:, 5, 1], table[:, 5, 0])  # direction of the first side
    for lo in (-math.pi, -math.pi / 2, 0.0, math.pi / 2):
        share = ((first_dir >= lo) & (first_dir < lo + math.pi / 2)).double().mean()
        assert share == pytest.approx(0.25, abs=0.06)
    square = Polygon(points_min=4, points_max=4, speed_min_mps=1.0, speed_max_mps=1.0, random_rotation=False)
    sq = square.sample(1, T64, gen())[0]
    side = 2 * 0.5 * math.sin(math.pi / 4)
    k = round(side / 1.0 / DT)  # the first corner
    corner = sq[:, :2].diff(dim=0).norm(dim=-1)
    assert corner[: k - 1].min() == pytest.approx(DT, abs=1e-9)
    assert (sq[2 * k, :2] - sq[0, :2]).norm().item() == pytest.approx(2 * side / math.sqrt(2), abs=0.03)
    assert sq[:, :2].abs().max() <= 2 * side + 1e-9


def test_csv_separator_detection_edge_cases(tmp_path):
    # no separator on the header line: read as one comma-separated column, reported as such
    path = tmp_path / "one.csv"
    path.write_text("txyz\n0\n1\n")
    with pytest.raises(ConfigError) as info:
        load_csv_reference(path)
    assert str(info.value) == (
        "traj.path: one.csv is missing column(s) t, x, y, z; required: t, x, y, z "
        "(header read as ['txyz'] with separator ',')"
    )
    # a comma wins over a ';' inside a column name
    both = tmp_path / "both.csv"
    both.write_text("t,x,y,z,note;s\n0,0,0,0,a\n1,1,0,0,b\n")
    assert load_csv_reference(both)[1].tolist() == [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]


def test_csv_loop_period_is_the_last_time(tmp_path):
    fam = CsvReference(str(write_csv(tmp_path / "ref.csv", CSV_ROWS)), loop=True)
    table = fam.sample(1, T64, gen())
    assert torch.allclose(table[0, 175], table[0, 75])  # 3.5 s = 1.5 s + one 2 s period
    assert not torch.allclose(table[0, 175], table[0, 25])


def test_polygon_keeps_moving_to_the_end_of_the_table():
    """Enough vertex visits for the fastest drone on the shortest sides: no drone holds still
    before the table ends."""
    fam = Polygon(points_min=3, points_max=6, speed_min_mps=1.6, speed_max_mps=1.6)
    t = torch.arange(1001, dtype=torch.float64) * DT  # 20 s
    table = fam.sample(300, t, gen(6))
    speed_end = table[:, -3:].diff(dim=1).norm(dim=-1) / DT
    assert speed_end.min() > 1.5
    star = Polygon(**STAR)
    end = star.sample(1, t, gen())[0, -3:].diff(dim=0).norm(dim=-1) / DT
    assert end.min() > 0.99


def test_star_visits_vertices_counterclockwise_every_second_one():
    """{5/2}: after the first vertex (0.7, 0) the next is 2 × 72° = 144° further counterclockwise
    (the authors' star: vertices 0, 2, 4, 1, 3 at angles 0°, 72°, ... as refs/pointed_star.py)."""
    star = Polygon(**STAR)
    table = star.sample(1, T64, gen())[0]
    side = 2 * 0.7 * math.sin(2 * math.pi / 5)
    k = 50 + round(side / DT)  # 1 s lead-in, then one side at 1 m/s
    angle = math.radians(144)
    expect = torch.tensor([0.7 * math.cos(angle), 0.7 * math.sin(angle)], dtype=torch.float64)
    assert torch.allclose(table[k, :2], expect, atol=0.02)


def test_polygon_step_must_be_coprime_with_every_count():
    with pytest.raises(ValueError, match="traj.step: must be >= 1 and coprime"):
        Polygon(points_min=3, points_max=4, step=2)  # a {4/2} is not a polygon
    Polygon(points_min=5, points_max=5, step=2)


def test_polygon_point_counts_cover_their_range_and_sides_are_exact():
    """At 1 m/s a {p} polygon of radius r closes after p · 2 r sin(π/p) seconds: every count
    3..6 occurs, and a square's first corner is reached at exactly its side length."""
    r = 0.5
    period = {p: p * 2 * r * math.sin(math.pi / p) for p in range(3, 7)}
    fam = Polygon(speed_min_mps=1.0, speed_max_mps=1.0)
    t = torch.tensor([0.0, *period.values()], dtype=torch.float64)
    table = fam.sample(400, t, gen(8))
    closed = table[:, 1:, :2].norm(dim=-1) < 1e-9  # [n, 4]: back at the origin at that period
    assert closed.sum(1).max() == 1 and closed.all(0).logical_not().all()
    assert closed.any(0).all()  # every vertex count was drawn
    square = Polygon(points_min=4, points_max=4, speed_min_mps=1.0, speed_max_mps=1.0, random_rotation=False)
    side = 2 * r * math.sin(math.pi / 4)
    corner = square.sample(1, torch.tensor([side], dtype=torch.float64), gen())[0, 0, :2]
    expect = torch.tensor(
        [r * math.cos(math.pi / 2 + math.pi / 2) - 0.0, r * math.sin(math.pi) - r], dtype=torch.float64
    )
    assert torch.allclose(corner, expect, rtol=0, atol=1e-12)


def test_chained_poly_starts_and_ends_without_acceleration_and_moves_to_the_end():
    fam = ChainedPoly()
    like = torch.zeros((), dtype=torch.float64)
    knot_t, coeffs = fam.sample_pieces(64, 10.0, gen(11), like)
    # a(0) of the first piece and a(h) of the last one: p'' = 2 c2 + 6 c3 h + 12 c4 h² + 20 c5 h³
    assert coeffs[:, 0, 2].abs().max() < 1e-9
    h = (knot_t[:, -1] - knot_t[:, -2])[:, None]
    c = coeffs[:, -1]
    acc_end = 2 * c[:, 2] + 6 * c[:, 3] * h + 12 * c[:, 4] * h**2 + 20 * c[:, 5] * h**3
    assert acc_end.abs().max() < 1e-6
    table = fam.sample(64, T_GRID, gen(11))
    assert table.dtype == torch.float32
    speed_late = (table[:, -100:].diff(dim=1).norm(dim=-1) / DT).mean(1)  # the last 2 s
    assert (speed_late > 0.05).float().mean() > 0.9


def test_seeded_draws_with_its_own_seed_only():
    from datt.refs.composite import Seeded

    fam = Seeded(Zigzag(), seed=3)
    a, b = fam.sample(4, T64, gen(1)), fam.sample(4, T64, gen(2))
    assert torch.equal(a, b) and torch.equal(a, Zigzag().sample(4, T64, gen(3)))


def test_fixed_caches_per_time_grid():
    fam = Fixed(Zigzag(), seed=4)
    short = fam.sample(2, T64, gen())
    other_end = T64.clone()
    other_end[-1] += 5.0  # same length, a different last time
    assert torch.equal(fam.sample(3, T64, gen(9))[0], short[0])
    far = fam.sample(2, other_end, gen())
    assert far.shape == short.shape and not torch.equal(far, short)  # drawn for that grid, not the cached one


def test_seeded_and_fixed_default_to_seed_zero():
    """The curriculum's fixed zigzag and the bank's seeded groups say seed 0 when no seed is given."""
    from datt.refs.composite import Fixed, Seeded

    t = torch.linspace(0.0, 5.0, 11)
    for cls in (Seeded, Fixed):
        default, zero, one = (cls(Zigzag(), *s).sample(3, t, torch.Generator()) for s in ((), (0,), (1,)))
        assert torch.equal(default, zero) and not torch.equal(default, one)


@pytest.mark.parametrize(
    "radius_m, points, step", [(0.5, (3, 9), 1), (2.0, (3, 9), 1), (0.5, (4, 5), 3), (2.0, (4, 5), 3)]
)
def test_polygons_keep_moving_to_the_end_of_a_long_episode(radius_m, points, step):
    """Enough vertices are laid out for the shortest side (at the most points for {p/1}, at the
    fewest for {4/3} vs {5/3}) at the top speed: every drone still moves at its speed in the last second
    of a 60 s episode, and the centred shape's lead-in defaults to none (the path starts at the
    origin and leaves it at once)."""
    t = torch.arange(0.0, 60.0 + 1e-9, 0.02)
    family = Polygon(*points, step=step, radius_m=radius_m, speed_min_mps=2.5, speed_max_mps=3.0)
    pos = family.sample(64, t, torch.Generator().manual_seed(0))  # [64, T, 3]
    speed = (pos[:, 1:] - pos[:, :-1]).norm(dim=-1) / 0.02
    assert speed[:, -50:].min() > 0.5  # a corner cut inside one 20 ms step shows as less; stuck would be 0
    centred = Polygon(through_origin=False, random_rotation=False).sample(1, t[:5], torch.Generator())
    assert torch.equal(centred[0, 0], torch.zeros(3)) and centred[0, 1].norm() > 0.01

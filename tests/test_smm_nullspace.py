"""Ground-truth SMMs by nullspace projection, and the `smm` command."""
import math

import numpy as np
import pytest

from require import missing

try:
    import torch
except ImportError:
    missing("torch is not installed (`make setup` installs the [train] extra)")

from armbridge.errors import ArmbridgeError
from armbridge.smm import nullspace
from armbridge.smm.arms import get_smm_arm
from armbridge.smm.manifold import SmmSet

torch.set_num_threads(1)

# planar3r, links l = 1 (arms.py): 2 branches for r < 1, 1 for 1 < r < 3, 0 beyond; singular at r = 1 and 3.
RADII = np.array([0.0, 0.3, 0.7, 1.5, 2.5, 2.9, 3.2])
COUNTS = np.array([2, 2, 2, 1, 1, 1, 0])


def _wrapped(a: np.ndarray) -> np.ndarray:
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def _max_fk_error(arm, smm: SmmSet, x: np.ndarray) -> float:
    worst = 0.0
    for l in range(len(smm)):
        for b in smm.branches(l):
            worst = max(worst, float(arm.fk_error(b, np.broadcast_to(x[l], (b.shape[0], arm.m)).copy()).max()))
    return worst


@pytest.fixture(scope="module")
def planar() -> tuple[np.ndarray, SmmSet]:
    x = np.stack([RADII * np.cos(0.4), RADII * np.sin(0.4)], 1)
    return x, nullspace.compute(get_smm_arm("planar3r"), x, device="cpu")


def test_null_vector_is_eq6() -> None:
    jac = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    # n_3 = (-1)^3 det(I) = -1; the other minors are singular.
    torch.testing.assert_close(nullspace.null_vector(jac), torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    arm = get_smm_arm("spatial7r")
    q = torch.rand(5, 7, dtype=torch.float64)
    j = arm.jacobian(q)
    nv = nullspace.null_vector(j)
    assert float((j @ nv[..., None]).abs().max()) < 1e-10
    assert float(nv.norm(dim=-1).min()) > 1e-6
    with pytest.raises(ArmbridgeError, match="n-1"):
        nullspace.null_vector(torch.zeros(2, 4, dtype=torch.float64))


def test_planar3r_branch_counts_match_hand_derivation(planar) -> None:
    _, smm = planar
    np.testing.assert_array_equal(smm.count, COUNTS)
    assert not smm.singular.any()
    assert smm.points.shape == (len(RADII), 2, 128, 3)
    assert np.isnan(smm.points[3:, 1]).all() and np.isnan(smm.points[-1]).all()


def test_every_point_reaches_its_target_and_angles_are_wrapped(planar) -> None:
    x, smm = planar
    assert _max_fk_error(get_smm_arm("planar3r"), smm, x) < 1e-9
    valid = smm.points[~np.isnan(smm.points)]
    assert valid.min() > -math.pi and valid.max() <= math.pi


def test_arm3r_branch_counts_match_hand_derivation() -> None:
    """Links 0.19, 0.12, 0.07: the 2R sub-chain reaches d in [0.07, 0.31] and must reach
    d(psi) = |x - 0.07 e(psi)| in [|r - 0.07|, r + 0.07]; both elbows stay apart (2 branches)
    only when that range lies inside, i.e. 0.14 < r < 0.24."""
    r = np.array([0.1, 0.19, 0.3, 0.4])
    smm = nullspace.compute(get_smm_arm("arm3r"), np.stack([r, np.zeros(4)], 1), device="cpu", seeds=32)
    np.testing.assert_array_equal(smm.count, [1, 2, 1, 0])


def test_planar3r_branch_shapes(planar) -> None:
    """Inside r < 1 each branch winds joint 1 once (the last link circles the target, which
    the 2R sub-chain's reach circle encloses); branches are uniform in arc length."""
    _, smm = planar
    for l in range(3):
        for b in smm.branches(l):
            steps = _wrapped(np.diff(np.vstack([b, b[:1]]), axis=0))
            assert abs(abs(steps[:, 0].sum()) - 2 * math.pi) < 1e-9
            gaps = np.linalg.norm(steps, axis=1)
            assert gaps.max() / gaps.min() < 1.05
    for l in (3, 4, 5):  # one branch: elbow up and down joined, joint 1 swings back
        (b,) = smm.branches(l)
        steps = _wrapped(np.diff(np.vstack([b, b[:1]]), axis=0))
        assert abs(steps[:, 0].sum()) < 1e-9


def test_branches_follow_plus_null_vector() -> None:
    arm = get_smm_arm("spatial4r")
    x = np.array([[2.0, 1.0, 0.5], [0.5, -1.5, 2.0]])
    smm = nullspace.compute(arm, x, device="cpu")
    for l in range(2):
        for b in smm.branches(l):
            nv = nullspace.null_vector(arm.jacobian(torch.tensor(b)))
            step = torch.tensor(_wrapped(np.roll(b, -1, 0) - b))
            assert bool(((nv * step).sum(-1) > 0).all())


def test_singular_radii_are_flagged() -> None:
    x = np.array([[0.999, 0.0], [1.001, 0.0], [2.999, 0.0]])
    smm = nullspace.compute(get_smm_arm("planar3r"), x, device="cpu")
    assert smm.singular.all()


def test_other_seeds_give_the_same_branches() -> None:
    arm = get_smm_arm("spatial4r")
    g = torch.Generator().manual_seed(7)
    q = (torch.rand(8, 4, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    x = arm.task(q).numpy()
    a = nullspace.compute(arm, x, device="cpu", seed=0)
    b = nullspace.compute(arm, x, device="cpu", seed=1, seeds=48)
    np.testing.assert_array_equal(a.count, b.count)
    assert a.count.min() >= 1
    for l in range(len(x)):
        for br in a.branches(l):
            spacing = np.median(np.linalg.norm(_wrapped(np.roll(br, -1, 0) - br), axis=1))
            # Every point of a branch of `a` lies on one branch of `b` (within half a sample).
            dist = [np.linalg.norm(_wrapped(br[:, None] - other[None]), axis=2).min(1).max()
                    for other in b.branches(l)]
            assert min(dist) < 0.6 * spacing


def test_smm_of_a_rotated_location_is_the_canonical_one_shifted_in_theta1() -> None:
    arm = get_smm_arm("spatial4r")
    x = np.array([[1.0, 2.0, 0.5]])
    c, shift = arm.canonical(x)
    phi = shift[:, 0]
    rotated = nullspace.compute(arm, x, device="cpu")
    canon = nullspace.compute(arm, arm.uncanonical(c), device="cpu", seed=3)
    assert rotated.count[0] == canon.count[0] >= 1
    for br in canon.branches(0):
        shifted = br.copy()
        shifted[:, 0] = _wrapped(shifted[:, 0] + phi[0])
        spacing = np.median(np.linalg.norm(_wrapped(np.roll(br, -1, 0) - br), axis=1))
        dist = [np.linalg.norm(_wrapped(shifted[:, None] - other[None]), axis=2).min(1).max()
                for other in rotated.branches(0)]
        assert min(dist) < 0.6 * spacing


def test_out_of_reach_gives_count_zero() -> None:
    for name, x in (("planar3r", [[3.5, 0.0]]), ("spatial4r", [[7.0, 0.0, 0.0]]),
                    ("spatial7r", [[0.0, 0.0, 12.0, 0.0, 0.0, 0.0]])):
        smm = nullspace.compute(get_smm_arm(name), np.array(x), device="cpu", seeds=8)
        assert smm.count.tolist() == [0]
        assert np.isnan(smm.points).all()


@pytest.mark.parametrize("name, count", [("spatial4r", 4), ("spatial7r", 2)])
def test_spatial_arms_give_closed_accurate_branches(name: str, count: int) -> None:
    arm = get_smm_arm(name)
    g = torch.Generator().manual_seed(11)
    q = (torch.rand(count, arm.n, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    x = arm.task(q).numpy()
    smm = nullspace.compute(arm, x, device="cpu", seeds=32)
    assert (smm.count >= 1).all()
    assert _max_fk_error(arm, smm, x) < 1e-9
    for l in range(count):
        for b in smm.branches(l):
            gaps = np.linalg.norm(_wrapped(np.diff(np.vstack([b, b[:1]]), axis=0)), axis=1)
            assert gaps.max() < 1.5 * np.median(gaps)  # closed: the last point leads back to the first
        # The configuration the location came from lies on one of the branches.
        d = min(np.linalg.norm(_wrapped(b - q[l].numpy()), axis=1).min() for b in smm.branches(l))
        assert d < np.median(np.linalg.norm(_wrapped(np.diff(smm.branches(l)[0], axis=0)), axis=1))


def test_empty_batch() -> None:
    smm = nullspace.compute(get_smm_arm("planar3r"), np.zeros((0, 2)))
    assert len(smm) == 0 and smm.points.shape == (0, 1, 128, 3)


def test_bad_input_raises_clear_errors() -> None:
    arm = get_smm_arm("planar3r")
    with pytest.raises(ArmbridgeError, match=r"shape \(L, 2\)"):
        nullspace.compute(arm, np.zeros((2, 3)))
    with pytest.raises(ArmbridgeError, match="finite"):
        nullspace.compute(arm, np.array([[np.nan, 0.0]]))
    with pytest.raises(ArmbridgeError, match="step must be in"):
        nullspace.compute(arm, np.zeros((1, 2)), step=1.0)
    with pytest.raises(ArmbridgeError, match="one redundant joint"):
        from armbridge.robots.dh import DHChain

        nullspace.compute(DHChain("r2", [1.0, 1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], "xy"), np.zeros((1, 2)))


# ------------------------------------------------------------------ the command

def _app():
    import typer
    from armbridge.smm.command import smm_cmd

    app = typer.Typer()
    app.command("smm")(smm_cmd)
    app.command("other")(lambda: None)  # two commands keep the subcommand name
    return app


def test_smm_command_prints_branches_and_writes_png(tmp_path) -> None:
    from typer.testing import CliRunner

    png = tmp_path / "fig.png"
    result = CliRunner().invoke(_app(), ["smm", "planar3r", "--at", "0.3,0", "--png", str(png)])
    assert result.exit_code == 0, result.output
    assert "2 SMM branches" in result.output
    assert "full" in result.output  # joint 1 winds all the way round
    assert png.stat().st_size > 1000


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["planar3r", "--at", "0.3"], "needs 2 comma-separated numbers, got 1"),
        (["spatial4r", "--at", "1,x,2"], "must be numbers"),
        (["puma", "--at", "1,2"], "unknown SMM robot 'puma'"),
        (["planar3r", "--at", "1,2", "--method", "magic"], "--method must be one of"),
    ],
)
def test_smm_command_bad_input(args: list[str], message: str) -> None:
    from typer.testing import CliRunner

    result = CliRunner().invoke(_app(), ["smm", *args])
    assert isinstance(result.exception, ArmbridgeError)
    assert message in str(result.exception)


def test_smm_command_out_of_reach() -> None:
    from typer.testing import CliRunner

    result = CliRunner().invoke(_app(), ["smm", "planar3r", "--at", "3.5,0"])
    assert result.exit_code == 0, result.output
    assert "0 SMM branches" in result.output and "out of reach" in result.output


def test_smm_command_learned_method_is_wired(monkeypatch) -> None:
    from typer.testing import CliRunner

    from armbridge.smm import learned
    calls: dict = {}

    class Fake:
        def compute(self, x, correct_iters=0):
            calls.update(x=x, correct=correct_iters)
            return nullspace.compute(get_smm_arm("planar3r"), x, seeds=8)

    def load(cls, folder, robot=None):
        calls.update(folder=str(folder), robot=robot)
        return Fake()

    monkeypatch.setattr(learned.LearnedSmm, "load", classmethod(load))
    result = CliRunner().invoke(_app(), ["smm", "planar3r", "--at", "1.5,0", "--method", "learned", "--correct", "2"])
    assert result.exit_code == 0, result.output
    assert "1 SMM branch " in result.output and "[learned" in result.output
    assert calls["folder"].endswith("smm-planar3r") and calls["robot"] == "planar3r" and calls["correct"] == 2
    np.testing.assert_array_equal(calls["x"], [[1.5, 0.0]])

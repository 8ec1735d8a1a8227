"""The one damped-least-squares step under the MASR's numeric IK and the IK-NN's refinement (ik.masr_dls)."""
import numpy as np

from armbridge.ik import masr_dls
from armbridge.robots import MASR5

ARM = MASR5
L = np.ascontiguousarray(ARM.link_lengths, float)
RJ = np.ascontiguousarray(ARM.r, float)
TOTAL = float(ARM.total_length)
E_P, E_PHI = masr_dls.E_P, masr_dls.E_PHI


def rand_q(rng, count):
    tb = ARM.theta_b
    return np.concatenate([rng.uniform(-tb, tb, (count, ARM.n)), rng.uniform(0, TOTAL, (count, 1))], 1)


def scaled_pose(q, link):
    """(x / e_p, y / e_p, phi / e_phi) of the MA with d on `link` (fk, with phi unwrapped as the kernel's)."""
    x = ARM.fk(q)
    return np.array([x[0] / E_P, x[1] / E_P, np.sum(q[:link + 1]) / E_PHI])


def test_step_is_the_damped_solve_on_the_pose_jacobian():
    rng = np.random.default_rng(0)
    n = ARM.n
    jp = np.empty((n + 1, 2))
    J = np.zeros((3, n + 1))
    step = np.empty(n + 1)
    for q, xg in zip(rand_q(rng, 40), ARM.fk(rand_q(rng, 40))):
        link = int(ARM.locate(q[-1])[0])
        lo, hi = ARM.margin_range(link)
        q[-1] = np.clip(q[-1], float(lo), float(hi))  # d well inside its link: fk is smooth there
        frozen = rng.random(n) < 0.3
        s_theta, s_d, lam = rng.uniform(0.5, 2.0), rng.uniform(0.05, 0.2), 0.3
        ex, ey, ea, px, py, phi, lk = masr_dls.pose_error(q, xg, L, RJ, TOTAL, E_P, E_PHI, jp)
        assert lk == link
        masr_dls.dls_step(ex, ey, ea, px, py, phi, lk, jp, frozen, s_theta, s_d, lam * lam, E_P, E_PHI, J, step)
        # the Jacobian by central differences of fk, per s_theta rad and s_d m, frozen and distal columns zero
        ref = np.zeros((3, n + 1))
        for k in range(n + 1):
            if k < n and (k > link or frozen[k]):
                continue
            dq = np.zeros(n + 1)
            dq[k] = 1e-6
            ref[:, k] = (scaled_pose(q + dq, link) - scaled_pose(q - dq, link)) / 2e-6 * (s_theta if k < n else s_d)
        np.testing.assert_allclose(J, ref, atol=1e-6 * np.abs(ref).max())
        e = np.array([ex, ey, ea])
        y = np.linalg.solve(ref @ ref.T + lam * lam * np.eye(3), e)
        scale = np.append(np.full(n, s_theta), s_d)
        np.testing.assert_allclose(step, ref.T @ y * scale, rtol=1e-6, atol=1e-12)


def test_both_loops_converge_on_reachable_goals():
    rng = np.random.default_rng(1)
    q_true = rand_q(rng, 60)
    for k in range(60):  # goals clear of the joints, so the margin does not move them
        link = int(ARM.locate(q_true[k, -1])[0])
        q_true[k, -1] = 0.5 * sum(float(v) for v in ARM.margin_range(link))
    xg = ARM.fk(q_true)
    lengths, rj, tb, total, js, ms = masr_dls._arrays(ARM)
    _, err = masr_dls.free_dls_batch(xg, rand_q(rng, 60), lengths, rj, tb, total, js, ms, E_P, E_PHI, 60, 0.5)
    assert np.mean(err < masr_dls.FREE_STOP) > 0.8
    # from the answer's neighbourhood on the right link, link_dls reaches the goal check over the margin
    start = q_true + rng.normal(0, 0.02, q_true.shape) * np.append(np.ones(ARM.n), 0.0)
    q, score = masr_dls.refine(ARM, xg, start, iters=30, with_score=True)
    np.testing.assert_array_equal(score <= 1.0, ARM.reaches(q, xg, E_P, E_PHI))
    assert np.mean(score <= 1.0) > 0.9
    assert ARM.holds_margin(q[:, -1]).all()

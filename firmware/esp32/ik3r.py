"""The board's Cartesian IK for the 3R drawing arm (issue 10 section 3; Murai,
Vairagi, Semwal sections 3.6-3.7): the int8 ANN of Table 2 (mlp.py) gives a
first answer, a fixed number of FABRIK passes refines it.

    ik = BoardIK(cfg, weights_bytes)        # ValueError when the file is bad
    q = ik.solve(x_m, y_m, theta_rad)       # [q1, q2, q3] rad in the limits, or None

solve():
1. None outside the safe disc cfg.IK_REGION_UM (the host's ik.region.safe_region).
2. The net on MinMax features: x, y over [-reach, reach], theta over
   [sum q_min, sum q_max] (reach = sum of LINK_LENGTHS_M, limits LIMITS_MRAD), as
   the host's ik/arm3r_ann.py scaler_bounds; its output mapped into the limits.
3. cfg.IK_FABRIK_PASSES FABRIK passes (section 3.6, the host's ik/fabrik.py Phase I
   and Phase II with the joint limits) with the pen angle theta fixing the last
   link: the wrist is w = t - d3 (cos theta, sin theta); Phase I pulls the elbow
   back from w with q3's limit, Phase II puts the root on the base and clips each
   angle (q3 = theta - q1 - q2 clipped), so every pass ends inside the limits.
4. None when the tip ends farther than cfg.IK_TOL_UM from the target.

The host's float64 reference of these steps is host/armbridge/ik/board_ik.py.
"""

import math

import mlp

TWO_PI = 2.0 * math.pi


def clip_angle(a: float, lo: float, hi: float) -> float:
    """The copy of angle a inside [lo, hi] or, when none is, the limit nearer around
    the circle (the host's ik/fabrik.py clip_angle)."""
    width = hi - lo
    m = (a - lo) % TWO_PI
    if m <= width:
        return lo + m
    if m - width <= TWO_PI - m:
        return hi
    return lo


class BoardIK:
    """IK from a config (LINK_LENGTHS_M, LIMITS_MRAD, IK_*) and a flat int8 file's bytes."""

    def __init__(self, cfg, weights) -> None:
        if weights is None:
            raise ValueError("IK weights %s missing" % (getattr(cfg, "IK_WEIGHTS", "?"),))
        if len(cfg.LINK_LENGTHS_M) != 3 or len(cfg.LIMITS_MRAD) != 3:
            raise ValueError("the board IK is for a 3-joint arm")
        net = mlp.FlatMLP(weights)
        if net.n_in != 3 or net.n_out != 3:
            raise ValueError("IK net takes %d and gives %d values; (x, y, theta) -> q needs 3 and 3"
                             % (net.n_in, net.n_out))
        self.net = net
        self.d = [float(v) for v in cfg.LINK_LENGTHS_M]
        self.lo = [lim[0] / 1000.0 for lim in cfg.LIMITS_MRAD]
        self.hi = [lim[1] / 1000.0 for lim in cfg.LIMITS_MRAD]
        reach = self.d[0] + self.d[1] + self.d[2]
        th_lo = self.lo[0] + self.lo[1] + self.lo[2]
        th_hi = self.hi[0] + self.hi[1] + self.hi[2]
        self.in_min = (-reach, -reach, th_lo)
        self.in_span = (2.0 * reach, 2.0 * reach, th_hi - th_lo)
        cx, cy, r = cfg.IK_REGION_UM
        self.cx = cx * 1e-6
        self.cy = cy * 1e-6
        self.r2 = (r * 1e-6) * (r * 1e-6)
        self.passes = int(cfg.IK_FABRIK_PASSES)
        self.tol = cfg.IK_TOL_UM * 1e-6
        self.error = -1.0  # tip error (m) of the last solve; -1 when the target was outside the disc

    def inside(self, x: float, y: float) -> bool:
        """In the safe disc (h_0 >= 0, eq. 6)."""
        dx = x - self.cx
        dy = y - self.cy
        return dx * dx + dy * dy <= self.r2

    def guess(self, x: float, y: float, theta: float) -> list:
        """The int8 net's q, mapped into the limits (step 2)."""
        p = (x, y, theta)
        f = [(p[i] - self.in_min[i]) / self.in_span[i] for i in range(3)]
        z = self.net.forward(f)
        q = []
        for i in range(3):
            v = self.lo[i] + z[i] * (self.hi[i] - self.lo[i])
            q.append(self.lo[i] if v < self.lo[i] else (self.hi[i] if v > self.hi[i] else v))
        return q

    def refine(self, x: float, y: float, theta: float, q: list, passes: int) -> list:
        """`passes` FABRIK passes from q with the last link along theta (step 3)."""
        d1, d2, d3 = self.d
        lo, hi = self.lo, self.hi
        wx = x - d3 * math.cos(theta)
        wy = y - d3 * math.sin(theta)
        ex = d1 * math.cos(q[0])  # the elbow: all a pass needs of the previous one
        ey = d1 * math.sin(q[0])
        q1, q2, q3 = q[0], q[1], q[2]
        for _ in range(passes):
            # Phase I: wrist fixed by theta, the elbow pulled back with q3's limit
            h2 = theta - clip_angle(theta - math.atan2(wy - ey, wx - ex), lo[2], hi[2])
            ex = wx - d2 * math.cos(h2)
            ey = wy - d2 * math.sin(h2)
            # Phase II: root on the base, each angle clipped into its limits
            q1 = clip_angle(math.atan2(ey, ex), lo[0], hi[0])
            ex = d1 * math.cos(q1)
            ey = d1 * math.sin(q1)
            q2 = clip_angle(math.atan2(wy - ey, wx - ex) - q1, lo[1], hi[1])
            q3 = clip_angle(theta - q1 - q2, lo[2], hi[2])
        return [q1, q2, q3]

    def tip(self, q: list) -> tuple:
        """Forward kinematics, eq. (3): the tip (x, y) in m."""
        d1, d2, d3 = self.d
        a = q[0]
        b = a + q[1]
        c = b + q[2]
        return (d1 * math.cos(a) + d2 * math.cos(b) + d3 * math.cos(c),
                d1 * math.sin(a) + d2 * math.sin(b) + d3 * math.sin(c))

    def solve(self, x: float, y: float, theta: float):
        """[q1, q2, q3] (rad, inside the limits) putting the tip on (x, y) m with the
        pen at theta rad, or None: outside the safe disc, or not within IK_TOL_UM."""
        if not self.inside(x, y):
            self.error = -1.0
            return None
        q = self.refine(x, y, theta, self.guess(x, y, theta), self.passes)
        tx, ty = self.tip(q)
        self.error = math.sqrt((tx - x) * (tx - x) + (ty - y) * (ty - y))
        if self.error > self.tol:
            return None
        return q

"""PID: clamp, anti-windup, derivative on measurement, feed-forward."""

from pid import PID


def test_proportional_and_clamp():
    p = PID(2.0)
    assert abs(p.update(0.1, 0.0, 0.01) - 0.2) < 1e-9
    assert p.update(10.0, 0.0, 0.01) == 1.0
    assert p.update(-10.0, 0.0, 0.01) == -1.0


def test_feed_forward():
    p = PID(0.0, kff=0.2)
    assert abs(p.update(0.0, 0.0, 0.01, 3.0) - 0.6) < 1e-9


def test_derivative_on_measurement_no_setpoint_kick():
    p = PID(0.0, kd=1.0)
    assert p.update(0.0, 0.0, 0.01) == 0.0
    assert p.update(5.0, 0.0, 0.01) == 0.0           # set-point step: no kick
    u = p.update(5.0, 0.001, 0.01)                   # measurement rises 0.1 rad/s
    assert abs(u - (-0.1)) < 1e-9


def test_integrator_accumulates():
    p = PID(0.0, ki=1.0)
    for _ in range(100):
        u = p.update(0.5, 0.0, 0.01)
    assert abs(u - 0.5) < 1e-6


def test_anti_windup():
    p = PID(1.0, ki=10.0)
    for _ in range(1000):                            # saturated for 10 s
        assert p.update(5.0, 0.0, 0.01) == 1.0
    assert p.integ <= 1.0
    # once the error reverses the output leaves saturation at once
    u = p.update(-0.2, 0.0, 0.01)
    assert u < 1.0
    for _ in range(50):
        u = p.update(-0.2, 0.0, 0.01)
    assert u < 0.0


def test_reset_and_gains():
    p = PID(1.0, ki=1.0)
    for _ in range(10):
        p.update(1.0, 0.0, 0.01)
    p.reset()
    assert p.integ == 0.0
    p.set_gains(3.0, 0.0, 0.0)
    assert abs(p.update(0.1, 0.0, 0.01) - 0.3) < 1e-9


def test_closes_loop_on_servo_plant():
    # velocity = effort * 5 rad/s behind a 30 ms lag, default-like gains
    p = PID(8.0, 2.0, 0.15, 0.2)
    q = 0.0
    v = 0.0
    for _ in range(150):                             # 1.5 s at 100 Hz
        u = p.update(1.0, q, 0.01)
        for _ in range(10):
            v += (5.0 * u - v) * (1.0 / 30.0)
            q += v * 0.001
    assert abs(q - 1.0) < 0.01

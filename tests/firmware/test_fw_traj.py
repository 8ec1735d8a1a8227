"""Trajectory: no jumps, speed stretching, carry-over, hold, queue capacity,
the ramp into a narrowed range."""

from traj import Traj


def _run(t, steps, dt=10):
    evs = []
    for _ in range(steps):
        evs += t.step(dt)
    return evs


def test_queue_capacity_and_free():
    t = Traj(3, qsize=4)
    for i in range(4):
        assert t.push(i, 100, [0, 0, 0])
    assert t.free() == 0
    assert not t.push(9, 100, [0, 0, 0])
    t.flush()
    assert t.free() == 4 and not t.busy()


def test_starts_from_current_set_point_without_jump():
    t = Traj(3, vmax=[3000] * 3)
    t.set_point([1000, -1000, 0])
    t.push(1, 500, [1500, -1500, 100])
    evs = t.step(10)
    assert evs == [("START", 1)]
    assert t.sp == [1000.0, -1000.0, 0.0]            # starts where it stood
    prev = list(t.sp)
    done = []
    for _ in range(60):
        done += t.step(10)
        for j in range(3):
            assert abs(t.sp[j] - prev[j]) <= 10.0 + 1e-6   # 1000 mrad/s * 10 ms
        prev = list(t.sp)
    assert done == [("DONE", 1, [1500, -1500, 100])]
    assert t.sp == [1500.0, -1500.0, 100.0]


def test_linear_interpolation_and_velocity():
    t = Traj(1, vmax=[100000])
    t.set_point([0])
    t.push(7, 100, [1000])
    t.step(10)                                        # start, t = 0
    t.step(10)
    assert abs(t.sp[0] - 100.0) < 1e-9
    assert abs(t.vel[0] - 10000.0) < 1e-9
    t.step(40)
    assert abs(t.sp[0] - 500.0) < 1e-9


def test_segments_chain_from_previous_end_with_carry_over():
    t = Traj(1, vmax=[100000])
    t.set_point([0])
    t.push(1, 25, [250])
    t.push(2, 100, [1250])
    evs = _run(t, 3)                                   # t = 0, 10, 20
    assert evs == [("START", 1)]
    evs = t.step(10)                                   # 30: seg 1 ends at 25, 5 ms into seg 2
    assert evs == [("DONE", 1, [250]), ("START", 2)]
    assert abs(t.sp[0] - 300.0) < 1e-9                 # 250 + 1000 * 5/100
    evs = _run(t, 10)
    assert evs == [("DONE", 2, [1250])]
    assert t.sp[0] == 1250.0 and not t.busy()


def test_several_short_segments_in_one_step():
    t = Traj(1, vmax=[1000000])
    t.set_point([0])
    t.step(10)
    for i in range(5):
        t.push(i, 2, [i + 1])
    t.step(10)                                         # from rest: only START 0
    evs = t.step(10)
    done = [e[1] for e in evs if e[0] == "DONE"]
    assert done == [0, 1, 2, 3, 4]
    assert t.sp[0] == 5.0 and not t.busy()


def test_speed_stretching_reports_slow_and_limits_speed():
    t = Traj(3, vmax=[3000, 3000, 1000])
    t.set_point([0, 0, 0])
    t.push(5, 100, [100, 0, 600])                      # joint 3 needs 600 ms
    evs = t.step(10)
    assert evs == [("START", 5), ("SLOW", 5, 3)]
    assert abs(t.vel[2] - 1000.0) < 1e-6
    steps = 0
    done = []
    while not done:
        done = [e for e in t.step(10) if e[0] == "DONE"]
        steps += 1
    assert steps == 60


def test_no_slow_when_within_limit():
    t = Traj(1, vmax=[3000])
    t.set_point([0])
    t.push(1, 500, [1500])                             # exactly 3000 mrad/s
    assert t.step(10) == [("START", 1)]


def test_hold_freezes_segment_time():
    t = Traj(1, vmax=[100000])
    t.set_point([0])
    t.push(1, 100, [1000])
    _run(t, 4)
    sp = t.sp[0]
    t.hold = True
    assert _run(t, 20) == []
    assert t.sp[0] == sp and t.vel[0] == 0.0
    t.hold = False
    t.step(10)
    assert abs(t.sp[0] - (sp + 100.0)) < 1e-9
    assert _run(t, 6) == [("DONE", 1, [1000])]


def test_flush_keeps_set_point():
    t = Traj(1, vmax=[100000])
    t.set_point([0])
    t.push(1, 100, [1000])
    _run(t, 5)
    sp = t.sp[0]
    t.flush()
    assert not t.busy() and t.sp[0] == sp
    assert _run(t, 5) == [] and t.sp[0] == sp


def test_set_point_outside_range_ramps_in_at_vmax_with_one_limit_event():
    t = Traj(2, vmax=[1000, 1000])
    t.set_point([500, 0])
    t.set_range(0, 0, 200, 1000)                       # 300 mrad outside: 300 ms at 1000 mrad/s
    evs = []
    prev = t.sp[0]
    for _ in range(40):
        evs += t.step(10)
        assert prev - t.sp[0] <= 10.0 + 1e-9           # never faster than vmax
        prev = t.sp[0]
    assert evs == [("LIMIT", 1)]
    assert t.sp == [200.0, 0.0] and t.vel == [0.0, 0.0]
    assert _run(t, 5) == []                            # inside: no more events
    t.set_range(0, 300, 400, 500)                      # below the range now: up at 500 mrad/s
    assert t.step(10) == [("LIMIT", 1)]
    assert t.sp[0] == 205.0 and t.vel[0] == 500.0


def test_ramp_waits_for_hold_and_a_segment_takes_over():
    t = Traj(1, vmax=[1000])
    t.set_point([500])
    t.set_range(0, 0, 200, 1000)
    t.hold = True
    assert _run(t, 5) == [] and t.sp[0] == 500.0
    t.hold = False
    t.step(10)
    t.push(3, 10, [100])                               # from 490 to 100: stretched to vmax
    evs = t.step(10)
    assert evs == [("START", 3), ("SLOW", 3, 1)]
    prev = t.sp[0]
    for _ in range(50):
        t.step(10)
        assert prev - t.sp[0] <= 10.0 + 1e-9
        prev = t.sp[0]
    assert t.sp[0] == 100.0


def test_excludes_sees_queued_and_active_targets():
    t = Traj(2, vmax=[100000, 100000])
    t.set_point([0, 0])
    t.push(1, 100, [100, 0])
    t.push(2, 100, [300, 0])
    assert t.excludes(0, 0, 200) and not t.excludes(0, 0, 300)
    assert not t.excludes(1, 0, 0)
    _run(t, 11)                                        # 1 done, 2 active
    assert t.active_id == 2 and t.excludes(0, 0, 200)
    _run(t, 20)
    assert not t.busy() and not t.excludes(0, 0, 200)


def test_lower_vmax_replans_the_active_segment_without_a_jump():
    t = Traj(1, vmax=[100000])
    t.set_point([0])
    t.push(1, 100, [1000])
    _run(t, 5)                                         # start + 40 ms: at 400
    assert t.sp[0] == 400.0
    t.set_range(0, -5000, 5000, 1000)                  # 600 left at 1000 mrad/s: 600 ms
    assert t.sp[0] == 400.0 and abs(t.vel[0] - 1000.0) < 1e-9
    prev = t.sp[0]
    evs = []
    for _ in range(59):
        evs += t.step(10)
        assert 0.0 < t.sp[0] - prev <= 10.0 + 1e-9
        prev = t.sp[0]
    assert evs == [] and t.step(10) == [("DONE", 1, [1000])]


def test_dwell_waits_at_the_start_and_aux_changes_are_reported_once():
    t = Traj(1, 4)
    t.set_point([0])
    t.push(1, 100, [100], 0, 0)
    t.push(2, 100, [200], 50, 1)              # the pen goes down: 50 ms settle first
    t.push(3, 100, [300], 0, 1)
    evs = t.step(10)
    assert evs == [("AUX", 0), ("START", 1)]
    evs = []
    for _ in range(10):
        evs += t.step(10)
    assert ("AUX", 1) in evs and ("DONE", 1, [100]) in evs
    sp = t.sp[0]
    for _ in range(4):                         # 40 ms into the 50 ms dwell: no motion
        assert t.step(10) == []
        assert t.sp[0] == sp and t.vel[0] == 0.0
    evs = []
    for _ in range(25):
        evs += t.step(10)
    assert [e[0] for e in evs].count("AUX") == 0   # 3 has the same aux as 2
    assert ("DONE", 3, [300]) in evs and t.sp[0] == 300

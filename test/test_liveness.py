"""CameraWatch: stopped / publishing again, missing cameras without start-up races, the end of the input."""

from nrmpc_ros.frontend.liveness import CameraWatch

NAMES = ["/cam0", "/cam1", "/cam2"]


def publish(watch, cams, t0, t1, dt=0.1):
    events = []
    t = t0
    while t < t1:
        for i in cams:
            events += watch.seen(i, t)
        events += watch.check(t)
        t += dt
    return events


def test_a_camera_that_stops_while_the_others_publish_is_reported_once_and_again_when_back():
    w = CameraWatch(NAMES, timeout_s=1.0)
    assert publish(w, [0, 1, 2], 0.0, 2.0) == []
    events = publish(w, [0, 1], 2.0, 5.0)
    assert [lvl for lvl, _ in events] == ["warn"] and "camera /cam2 stopped publishing" in events[0][1]
    assert w.silent() == ["/cam2"]
    back = w.seen(2, 5.0)
    assert back[0][0] == "info" and "camera /cam2 is publishing again (silent for 3.1 s)" in back[0][1]
    assert w.silent() == []


def test_cameras_that_stop_together_end_the_input_without_a_fault():
    w = CameraWatch(NAMES, timeout_s=1.0)
    publish(w, [0, 1, 2], 0.0, 2.0)
    assert w.check(2.5) == []
    events = w.check(3.2)
    assert [lvl for lvl, _ in events] == ["ended"] and w.silent() == [] and w.ends == 1
    assert w.check(10.0) == []
    again = w.seen(0, 20.0)
    assert "the input resumed" in again[0][1] and w.ended is None


def test_a_camera_without_images_is_missing_only_after_the_others_published_for_the_timeout():
    """No false 'no image yet' while the first images are on their way (the start-up race)."""
    w = CameraWatch(NAMES, timeout_s=1.0)
    assert w.check(100.0) == []  # long after start, nothing published yet: nothing to say
    events = publish(w, [0, 1], 100.0, 100.9)
    assert events == [] and w.silent() == []
    events = publish(w, [0, 1], 100.9, 101.5)
    assert len(events) == 1 and "camera /cam2: no image yet" in events[0][1] and w.silent() == ["/cam2"]
    first = w.seen(2, 101.5)
    assert "camera /cam2 is publishing (its first image" in first[0][1] and w.silent() == []


def test_a_check_after_a_stall_of_the_process_judges_nothing():
    """A busy process runs its timer late, before the images that arrived meanwhile are taken from their
    queues: that check says nothing, the next one on time judges what came."""
    w = CameraWatch(NAMES, timeout_s=1.0, check_period_s=0.5)
    for k in range(5):
        t = 0.5 * k
        for i in range(3):
            w.seen(i, t)
        assert w.check(t) == []
    assert w.check(4.0) == [] and w.stalls == 1  # 2 s of silence seen by a check 1.5 s late
    for i in range(3):
        w.seen(i, 4.01)  # the images queued during the stall
    assert w.check(4.5) == [] and w.ended is None
    assert w.check(5.0) == [] and [lvl for lvl, _ in w.check(5.5)] == ["ended"]  # a real end: checks on time
    stalled = CameraWatch(NAMES, timeout_s=1.0)  # without the period every late check judges
    for i in range(3):
        stalled.seen(i, 2.0)
    assert stalled.check(2.0) == [] and [lvl for lvl, _ in stalled.check(4.0)] == ["ended"]

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

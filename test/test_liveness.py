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


def test_a_camera_that_stops_on_a_machine_busy_for_good_is_found():
    """Every check comes two periods late (the timer of a process that gets a share of a core): each judges
    the silences its predecessor saw, so a camera silent for 2.5 s is found, once, and the others' brief
    waits never read as a stop or an end."""
    w = CameraWatch(NAMES, timeout_s=1.0, check_period_s=0.5)
    events = []
    for k in range(1, 11):
        t = float(k)
        for i in range(3):
            if not (i == 2 and 3.0 < t < 6.0):  # camera 2 silent from 3 s to 6 s
                events += w.seen(i, t - 0.01)
        events += w.check(t)
    stops = [e for e in events if "stopped" in e[1]]
    assert w.stalls == 9 and len(stops) == 1 and "/cam2" in stops[0][1]
    assert "nothing for 1.0 s" in stops[0][1]  # its silence at the check before the one that found it
    assert [e for e in events if "publishing again" in e[1]] and not [e for e in events if e[0] == "ended"]


def in_bursts(watch, cams, t0, t1, burst_s, epoch=0, rate=10.0):
    """Frames stamped at ``rate`` from t0 to t1, received at the end of each ``burst_s`` interval; the watch
    checked every 0.1 s in between. Returns the events."""
    events, t = [], t0
    stamps = [t0 + k / rate for k in range(int((t1 - t0) * rate))]
    while t < t1:
        due = [s for s in stamps if t - burst_s < s <= t] if round((t - t0) / burst_s, 6) % 1 == 0 else []
        for s in due:
            for i in cams:
                events += watch.seen(i, t, s, epoch)
        events += watch.check(t)
        t = round(t + 0.1, 6)
    return events


def test_a_camera_that_delivers_in_bursts_is_neither_stopped_nor_ended_between_them():
    """A driver that buffers 2.5 s of frames: once a burst has shown the spread of its delays, the silences
    between bursts are waited through (1.5 x the spread); a stop is still found, later."""
    w = CameraWatch(NAMES, timeout_s=1.0)
    events = in_bursts(w, [0, 1, 2], 0.0, 20.0, 2.5)
    assert [e for e in events if e[0] == "ended"][:1] == [events[0]] and w.ends == 1, \
        "only the first silence, before any burst showed it, reads as an end"
    assert w.end_timeout(0, 20.0) > 3.5 and w.stop_timeout(0) < 1.5, \
        "cameras that buffer together: the silence is long, none comes behind the others"
    assert w.check(20.5) == [] and w.check(21.5)[0][0] == "ended", "a real end (the last burst at 17.5 s)"


def test_steady_cameras_keep_the_timeout_and_a_jump_back_starts_their_delays_afresh():
    w = CameraWatch(NAMES, timeout_s=1.0)
    in_bursts(w, [0, 1, 2], 0.0, 10.0, 0.1)
    assert w.end_timeout(0, 10.0) == 1.0 and w.stop_timeout(0) == 1.0
    w.seen(0, 10.0, 5.0)  # a frame stamped 5 s back, in the same epoch: a delay 5 s longer, 5 s behind the others
    assert w.end_timeout(0, 10.0) > 7.0 and w.stop_timeout(0) > 7.0
    w.seen(0, 10.1, -100.0, epoch=1)  # after a jump back in time: another timeline
    assert w.end_timeout(0, 10.1) == 1.0 and w.stop_timeout(0) == 1.0


def test_a_camera_that_buffers_alone_is_waited_for_and_a_stop_is_still_found():
    """One camera's driver buffers 2.5 s of frames while the others publish steadily: its frames come up to
    2.5 s behind theirs, so the silences between its bursts are no stop; a real stop is found later."""
    w = CameraWatch(NAMES, timeout_s=1.0)
    events, t = [], 0.0
    while t < 20.0:
        for i in (0, 1):
            events += w.seen(i, t, t)
        if t > 0 and round(t / 2.5, 6) % 1 == 0:
            for k in range(25):
                events += w.seen(2, t, t - 2.5 + 0.1 * (k + 1))
        events += w.check(t)
        t = round(t + 0.1, 6)
    assert [e for e in events if "stopped" in e[1]] == [] and w.stop_timeout(2) > 3.5
    assert w.stop_timeout(0) == 1.0, "the steady cameras keep the timeout"
    stop = []
    while t < 25.0:  # its driver fails after the burst at 17.5 s
        for i in (0, 1):
            stop += w.seen(i, t, t)
        stop += w.check(t)
        t = round(t + 0.1, 6)
    assert len(stop) == 1 and "camera /cam2 stopped publishing" in stop[0][1]


def test_a_stall_of_the_process_does_not_hide_a_camera_that_stops():
    """On a busy machine the process stalls for 2 s at a time and then takes every camera's waiting frames
    in stamp order: every camera's delays spread by the stall, none comes behind the others; a camera silent
    for 2.5 s is still found stopped (1 s timeout), and no stall reads as an end."""
    w = CameraWatch(NAMES, timeout_s=1.0)
    events, stamp = [], 0.0
    for k in range(12):  # every 2 s the frames that came meanwhile are taken at once
        taken = 2.0 * k + 2.0
        for cam_stamp in [s / 10 for s in range(round(stamp * 10), round(taken * 10))]:
            for i in range(3):
                if i == 2 and 10.0 <= cam_stamp < 12.5:  # camera 2 is silent for 2.5 s of stamps
                    continue
                events += w.seen(i, taken, cam_stamp)
        stamp = taken
        events += w.check(taken + 0.05)
        events += w.check(taken + 1.5)
    assert w.end_timeout(0, 24.0) > 2.5 and w.stop_timeout(0) < 1.5
    stops = [e for e in events if "stopped" in e[1]]
    assert len(stops) == 1 and "/cam2" in stops[0][1] and not [e for e in events if e[0] == "ended"]

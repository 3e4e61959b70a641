"""benchmarks/diagnostics/closure_diagnostics.py: closures of a saved run are found where the run
says, measured, and judged right or wrong by relations that span them."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.grid.closure import REFUSED_ALIAS as ALIAS, REFUSED_GAIN as GAIN, REFUSED_JUMP as JUMP
from jaxslam.grid.closure import REFUSED_SCORE as SCORE
from jaxslam.metrics.relations import Relations

from . import load_benchmark, turning_path

closure_diagnostics = load_benchmark("diagnostics/closure_diagnostics")
grid_common = load_benchmark("grid_common")


def _right_then_wrong(n: int = 1000):
    """``(truth, path, closed)``: a path along x, 0.1 m per scan, drifted 2 m sideways
    from scan 400, put back on the truth by a closure at scan 700, then moved 3 m off
    by one at scan 900 (``closed[i]`` is scan ``i + 1``)."""
    truth = np.stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    path = truth.copy()
    path[400:700, 1] += 2.0
    path[900:, 1] += 3.0
    closed = np.zeros(n - 1, bool)
    closed[[699, 899]] = True
    return truth, path, closed


def test_a_right_and_a_wrong_closure(tmp_path):
    """A path along x, 0.1 m per scan: drifted 2 m sideways from scan 400, put back on
    the truth by a closure at scan 700 (right), then moved 3 m off by one at scan 900
    (wrong). Relations from scans 100 and 150 (true poses) to scans 720 and 910 judge
    them."""
    n = 1000
    truth, path, closed = _right_then_wrong(n)
    conflict = np.zeros(n - 1)
    conflict[700:703] = [0.1, 0.3, 0.2]
    score = np.full(n - 1, 0.5)
    score[699] = 0.45  # scan 700, the closure
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=path, scan_times=np.arange(n, dtype=float), info_track_closed=closed,
             info_track_conflict=conflict, info_track_score=score)
    pairs = [(100, 720), (910, 150)]  # the second one stored backwards
    deltas = [truth[b] - truth[a] for a, b in pairs]  # headings are 0: frame = world axes
    relations = Relations(None, np.array([float(a) for a, _ in pairs]), np.array([float(b) for _, b in pairs]),
                          np.array(deltas), np.arange(1, 3))
    rows = closure_diagnostics.closures(str(run), relations)
    assert [r["scan"] for r in rows] == [700, 900]
    right, wrong = rows
    assert right["verdict"] == "R" and right["relation_error_m"] == pytest.approx(0.0, abs=1e-9)
    assert wrong["verdict"] == "W" and wrong["relation_error_m"] == pytest.approx(3.0)
    # Each jump holds that scan's 0.1 m of travel along x.
    assert right["jump_m"] == pytest.approx(np.hypot(0.1, 2.0)) and wrong["jump_m"] == pytest.approx(np.hypot(0.1, 3.0))
    # Path length from the start to scan 699 (the drift step at 400 included), then
    # from the closure at 700 to scan 899.
    assert right["travelled_m"] == pytest.approx(69.8 + np.hypot(0.1, 2.0))
    assert wrong["travelled_m"] == pytest.approx(19.9)
    assert right["conflict_after"] == pytest.approx(0.3) and right["score"] == pytest.approx(0.45)
    unjudged = closure_diagnostics.closures(str(run), None)
    assert [r["verdict"] for r in unjudged] == ["?", "?"]


def test_an_undone_closure_is_judged_on_the_path_as_tracked(tmp_path):
    """The wrong closure at scan 900 of the test above, undone at scan 930: the run
    reports scans 900..929 taken back (on the truth) and records the undo. The
    diagnostics list the closures at 700 and 900 (not the undo), judge 900 wrong on
    the path as tracked (3 m) and say where it was undone."""
    from jaxslam.datasets.geometry import se2_compose, se2_inverse

    n = 1000
    truth = np.stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    tracked = truth.copy()
    tracked[400:700, 1] += 2.0
    tracked[900:930, 1] += 3.0
    correction = np.array([0.0, 3.0, 0.0])
    reported = tracked.copy()
    reported[900:930] = se2_compose(se2_inverse(correction)[None], tracked[900:930])
    closed = np.zeros(n - 1, bool)
    closed[[699, 899, 929]] = True  # an undo sets track_closed too
    undo = np.zeros((n - 1, 4))
    undo[929] = [30.0, *correction]
    conflict = np.zeros(n - 1)
    conflict[900:930] = 0.25  # scans 901..930, watched in the wrong frame
    conflict[930:960] = 0.9  # after the undo: not the closure's
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=reported, scan_times=np.arange(n, dtype=float), info_track_closed=closed,
             info_track_conflict=conflict, info_track_score=np.full(n - 1, 0.5), info_track_undo=undo)
    pairs = [(100, 720), (150, 910)]
    relations = Relations(None, np.array([float(a) for a, _ in pairs]), np.array([float(b) for _, b in pairs]),
                          np.array([truth[b] - truth[a] for a, b in pairs]), np.arange(1, 3))
    rows = closure_diagnostics.closures(str(run), relations)
    assert [r["scan"] for r in rows] == [700, 900]
    assert [r["undone_at"] for r in rows] == [None, 930]
    # watched: scans 701.. (5 m of path at 0.1 m a scan: to scan 750) and 901..930
    assert rows[0]["watch_conflict"] == pytest.approx(0.0)
    assert rows[1]["watch_conflict"] == pytest.approx(0.25)
    assert rows[1]["verdict"] == "W" and rows[1]["relation_error_m"] == pytest.approx(3.0)
    assert rows[1]["jump_m"] == pytest.approx(np.hypot(0.1, 3.0))


def test_conflict_level_is_the_share_over_the_path_before_the_closure(tmp_path):
    """A straight path, 0.1 m per scan, a closure at scan 2500 (path 249.9 m): its level
    averages the scans 200 m to 20 m of path before it (scans about 500-2300), where the
    share is 0.2; the scans nearer the closure (0.6) and the ones before (0.9) do not count."""
    n = 3000
    path = np.stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    closed = np.zeros(n - 1, bool)
    closed[2499] = True  # info[i] is scan i + 1
    conflict = np.full(n - 1, 0.9)
    conflict[479:2320] = 0.2  # scans 480..2320, a margin around 500..2300
    conflict[2320:2499] = 0.6
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=path, scan_times=np.arange(n, dtype=float), info_track_closed=closed,
             info_track_conflict=conflict, info_track_score=np.full(n - 1, 0.5))
    (row,) = closure_diagnostics.closures(str(run), None)
    assert row["scan"] == 2500
    assert row["conflict_level"] == pytest.approx(0.2)


def test_heading_taken_back_after_a_closure(tmp_path):
    """The run drifts +1 deg a scan for 15 scans, a closure at scan 20 takes the 15 deg
    back, and the next five scans drift -3 deg each (all of it taken back again): share
    1. Where they do not, share 0."""
    turns = np.zeros(40)
    reference = turning_path(turns)
    drift = turns.copy()
    drift[4:19] += np.radians(1.0)  # increments ending at scans 5-19
    drift[19] -= np.radians(15.0)  # the closure's increment ends at scan 20
    back = drift.copy()
    back[20:25] += np.radians(3.0)  # scans 21-25 turn the frame back
    for trajectory, share in ((back, 1.0), (drift, 0.0)):
        error = grid_common.heading_errors(turning_path(trajectory), reference)
        fix, taken = closure_diagnostics.heading_taken_back(error, 20)
        assert fix == pytest.approx(-15.0, abs=1e-9)
        assert taken == pytest.approx(share, abs=1e-9)
    closed = np.zeros(40, bool)
    closed[19] = True
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=turning_path(back), scan_times=np.arange(41.0), info_track_closed=closed,
             info_track_conflict=np.zeros(40), info_track_score=np.full(40, 0.5))
    rows = closure_diagnostics.closures(str(run), None, reference)
    assert rows[0]["heading_fix_deg"] == pytest.approx(-15.0) and rows[0]["taken_back"] == pytest.approx(1.0)
    assert "taken_back" not in closure_diagnostics.closures(str(run), None)[0]


def test_bad_places_groups_the_wrong_relations_by_stretch_and_names_the_closures_there(tmp_path):
    """The path of the first test, 3 m off from its wrong closure at scan 900: relations
    from scans 100-149 to 900-949 are off by 3 m, those to 720-769 are right. With
    stretches of 100 scans, one group (1-9, 50 relations) holds the wrong ones, and it
    names the closure at 900 (wrong) but not the one at 700."""
    n = 1000
    truth, path, closed = _right_then_wrong(n)
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=path, scan_times=np.arange(n, dtype=float), info_track_closed=closed,
             info_track_conflict=np.zeros(n - 1), info_track_score=np.full(n - 1, 0.5))
    pairs = [(a, a + 620) for a in range(100, 150)] + [(a, a + 800) for a in range(100, 150)]
    deltas = [truth[b] - truth[a] for a, b in pairs]
    relations = Relations(None, np.array([float(a) for a, _ in pairs]), np.array([float(b) for _, b in pairs]),
                          np.array(deltas), np.arange(len(pairs)))
    rows = closure_diagnostics.closures(str(run), relations)
    place = closure_diagnostics.bad_places(str(run), relations, rows, window=100, top=2)
    assert place["over_1m"] == 50 and place["mean_m"] == pytest.approx(1.5)
    # scans 100-149 to 900-949: the stretches that start at scans 100 and 900
    assert place["place_1"] == "100-900: 50" and place["closures_1"] == "900:W"
    assert "place_2" not in place
    assert place["cause"] == "wrong"


def _taken(verdict: str, undone_at: int | None = None) -> dict:
    return {"verdict": verdict, "undone_at": undone_at}


@pytest.mark.parametrize("one_stretch, there, expected", [
    (True, [_taken("W")], "local"),
    (False, [_taken("R"), _taken("W")], "wrong"),  # a wrong closure kept decides over a right one
    (False, [_taken("W", 950), _taken("R", 980)], "undone"),
    (False, [_taken("R", 980), _taken("R")], "undone"),  # undone first: the later one came after
    (False, [_taken("R")], "late"),
    (False, [_taken("?", 930)], "unjudged"),
    (False, [_taken("W", 930)], "none"),  # the wrong one undone, no right one taken
    (False, [], "none"),
])
def test_the_cause_of_a_group_of_wrong_relations(one_stretch, there, expected):
    assert closure_diagnostics.cause(one_stretch, there) == expected


def test_the_tail_counts_the_causes_of_the_runs_over_twice_the_median():
    """Five runs with a median of 0.3 m: the two over 0.6 m are the tail, and only
    their causes are counted (the median run's wrong closure is not)."""
    places = [{"run": f"s{k}", "mean_m": mean, "cause": cause} for k, (mean, cause) in
              enumerate([(0.1, "late"), (0.2, "none"), (0.3, "wrong"), (0.9, "none"), (1.5, "wrong")])]
    tail = closure_diagnostics.tail_causes(places, 2.0)
    assert tail["median_m"] == pytest.approx(0.3) and tail["runs"] == ["s3", "s4"]
    assert tail["counts"] == {key: {"wrong": 1, "none": 1}.get(key, 0) for key in closure_diagnostics.CAUSES}


def test_the_first_place_where_most_relations_went_wrong_names_the_cause(tmp_path):
    """A path along x, 0.1 m per scan, 3 m off on scans 500-549 and 900-979 and on five
    scans of 300-319. Relations to 900-979 (80, all wrong) are the largest group, but the
    run went wrong first at 100-500 (50, all wrong), where a right closure was taken (so:
    late); 200-300 is earlier still, but only 5 of its 20 relations are wrong."""
    n = 1000
    truth = np.stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    path = truth.copy()
    path[500:550, 1] += 3.0
    path[900:980, 1] += 3.0
    path[300:305, 1] += 3.0
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=path, scan_times=np.arange(n, dtype=float))
    pairs = ([(100 + k, 500 + k) for k in range(50)] + [(100 + k, 900 + k) for k in range(80)]
             + [(200 + k, 300 + k) for k in range(20)])
    deltas = [truth[b] - truth[a] for a, b in pairs]
    relations = Relations(None, np.array([float(a) for a, _ in pairs]), np.array([float(b) for _, b in pairs]),
                          np.array(deltas), np.arange(len(pairs)))
    taken = [{"run": "run", "scan": 520, "verdict": "R", "undone_at": None},
             {"run": "run", "scan": 310, "verdict": "W", "undone_at": None}]
    place = closure_diagnostics.bad_places(str(run), relations, taken, window=100, top=3)
    assert [place[f"place_{k}"] for k in (1, 2, 3)] == ["100-900: 80", "100-500: 50", "200-300: 5"]
    assert place["first_place"] == "100-500: 50" and place["cause"] == "late"


def _search(*rows) -> np.ndarray:
    """``Info.track_search`` rows ``(kind, score, distance, refusals)`` after 20 scans
    that judged no candidate."""
    return np.concatenate([np.zeros((20, 4)), np.array(rows, float).reshape(-1, 4)])


@pytest.mark.parametrize("search, expected", [
    (_search(), "unsearched"),
    (_search([1, 0.2, 3.0, SCORE], [1, 0.3, 2.0, SCORE + GAIN]), "low"),
    # the best candidate that moves the pose decides, not the local match found again
    (_search([1, 0.5, 0.1, GAIN], [1, 0.4, 4.0, JUMP], [1, 0.2, 3.0, SCORE]), "far"),
    (_search([1, 0.4, 4.0, GAIN], [1, 0.3, 2.0, JUMP]), "flat"),
    (_search([1, 0.45, 4.0, ALIAS]), "alias"),
    (_search([1, 0.2, 0.1, SCORE]), "low"),  # none moves the pose: the best of all
    (_search([1, 0.45, 4.0, 0], [1, 0.4, 4.0, GAIN]), "unconfirmed"),  # won a scan, lost the next
    (_search([1, 0.45, 4.0, 0], [2, 0.4, 4.0, GAIN]), "unconfirmed"),
    # a win 0.1 m away is the local match climbed further, not a closure held
    (_search([1, 0.45, 0.1, 0], [2, 0.4, 0.1, GAIN], [1, 0.3, 4.0, SCORE]), "low"),
])
def test_no_right_closure_is_explained_by_what_the_search_did_there(search, expected):
    """With the stretch's ``Info.track_search`` a stretch without a right closure names
    why: no search, a candidate held but not confirmed, or the first test that refused
    the best candidate that moves the pose; without it the cause stays ``none``."""
    assert closure_diagnostics.cause(False, [_taken("W", 930)], search) == expected
    assert closure_diagnostics.cause(False, [], search) == expected
    assert closure_diagnostics.cause(False, [_taken("R")], search) == "late"  # a closure decides first
    assert closure_diagnostics.cause(False, [], None) == "none"


def test_the_search_record_of_the_first_bad_place_is_summarised(tmp_path):
    """The run of the first-place test without its closure at 520, saved with
    ``info_track_search``: the search ran on scans 510 and 512 of stretch 500 and its
    best candidate 4 m away was refused for its score, which names the cause and the
    ``search`` column; the same candidate at scan 620 (another stretch) does not count."""
    n = 1000
    truth = np.stack([0.1 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    path = truth.copy()
    path[500:550, 1] += 3.0
    search = np.zeros((n - 1, 4))
    search[509] = [1, 0.25, 4.0, SCORE]  # scan 510 (info[i] is scan i + 1)
    search[511] = [1, 0.3, 0.2, GAIN]
    search[619] = [1, 0.6, 4.0, JUMP]
    run = tmp_path / "run.npz"
    np.savez(run, trajectory=path, scan_times=np.arange(n, dtype=float), info_track_search=search)
    pairs = [(100 + k, 500 + k) for k in range(50)]
    relations = Relations(None, np.array([float(a) for a, _ in pairs]), np.array([float(b) for _, b in pairs]),
                          np.array([truth[b] - truth[a] for a, b in pairs]), np.arange(len(pairs)))
    place = closure_diagnostics.bad_places(str(run), relations, [], window=100, top=3)
    assert place["first_place"] == "100-500: 50" and place["cause"] == "low"
    assert place["search"] == "2 searched, 0 held; best 0.25 at 4.0 m (score)"

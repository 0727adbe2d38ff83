"""`zennav record --until-stream-end`'s tally (zennav.recording.SolutionTally): distinct solution times per ins
against the solutions of its finished stream; a resumed ins's repeats are counted, not taken for new ones."""
from __future__ import annotations

from zennav import messages as M
from zennav.recording import SolutionTally

K = M.Keys("car")


def _solution(t_ns: int) -> dict:
    return {"schema": "nav_solution", "t_ns": t_ns}


def _status(done: bool, solutions: int) -> dict:
    return {"schema": "nav_status", "stream": {"done": done, "solutions": solutions}}


def test_repeats_do_not_complete_the_tally_and_missing_is_exact():
    tally = SolutionTally()
    sol, st = K.nav_solution(), K.nav_status()
    for t in range(100):  # the first ins: 0..99, killed; 80..99 again from its checkpoint, then 100..109
        tally.add(sol, _solution(t))
    tally.add(st, _status(False, 80))
    for t in range(80, 110):
        tally.add(sol, _solution(t))
    assert not tally.ended() and not tally.complete()
    tally.add(st, _status(True, 112))  # 112 solutions in the stream: 2 were lost
    tally.add(sol, None)  # an invalid payload: ignored
    assert tally.ended() and not tally.complete()
    assert tally.missing() == {sol: 2} and tally.repeats == {sol: 20}
    for t in (110, 111):
        tally.add(sol, _solution(t))
    assert tally.complete() and tally.missing() == {sol: 0}
    assert tally.summary() == f"{sol}: 112 solutions, 20 repeated (a resumed ins's), 0 missing"


def test_a_solution_batch_counts_each_of_its_solutions():
    """An ins with --solution-batch: each time of a nav_solution_batch counts as one solution."""
    tally = SolutionTally()
    sol, st = K.nav_solution(), K.nav_status()
    tally.add(sol, {"schema": "nav_solution_batch", "t_ns": 49, "t_ns_list": list(range(50))})
    tally.add(sol, _solution(50))  # one the step-wise engine took, alone
    tally.add(sol, {"schema": "nav_solution_batch", "t_ns": 99, "t_ns_list": list(range(51, 100))})
    tally.add(st, _status(True, 100))
    assert tally.complete() and tally.repeats == {}

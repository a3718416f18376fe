"""The lockstep runner's round line: a run of hours says in its log when it will end."""

from active.lockstep import round_line


def test_round_line_gives_the_time_left_at_the_mean_pace():
    assert round_line(1, 20, 20, 819.4, 770.0) == (
        "lockstep round 2/20: 20 run(s) in 819 s; 18 round(s) left, about 3.9 h at this pace"
    )
    assert (
        round_line(6, 8, 2, 120.0, 100.0)
        == "lockstep round 7/8: 2 run(s) in 120 s; 1 round(s) left, about 2 min at this pace"
    )
    assert round_line(7, 8, 2, 120.0, 100.0) == "lockstep round 8/8: 2 run(s) in 120 s; all rounds done"

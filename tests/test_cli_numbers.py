"""Every number flag of every command refuses NaN and infinity at the edge, with one line naming
the flag (the commands then check their own ranges: positive seconds, rates in [0, 1), ...)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxstyle.cli.args import finite
from jaxstyle.cli.main import build_parser, main


def number_flags() -> list[tuple[str, str, int]]:
    """``(command, flag, how many values)`` of every flag whose type is :func:`finite`."""
    _, subs = build_parser()
    out = []
    for command, parser in subs.items():
        for action in parser._actions:
            if action.type is finite and action.option_strings:
                n = action.nargs if isinstance(action.nargs, int) else 1
                out.append((command, action.option_strings[0], n))
    return out


FLAGS = number_flags()


def test_every_float_flag_is_checked():
    # no command parses a plain float any more (a plain float accepts nan and inf)
    _, subs = build_parser()
    plain = [(c, a.option_strings) for c, p in subs.items() for a in p._actions if a.type is float]
    assert plain == [] and len(FLAGS) >= 20


@pytest.mark.parametrize("command, flag, n", FLAGS, ids=[f"{c}{f}" for c, f, _ in FLAGS])
def test_nan_and_infinity_are_refused_naming_the_flag(command, flag, n, tmp_path, capsys):
    for value in ("nan", "inf", "-inf", "1e999"):
        if value.startswith("-"):  # argparse reads "-inf" as an option unless it is joined with "="
            if n > 1:
                continue
            argv = command.split() + [f"{flag}={value}"]
        else:
            argv = command.split() + [flag] + [value] * n
        if command not in ("data generate", "data fetch", "data prepare", "render"):
            argv += ["--run", str(tmp_path / "run")]
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and f"argument {flag}" in err and "expected a finite number" in err, err
        assert not (tmp_path / "run").exists()  # refused before anything is written


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=12))
def test_finite_accepts_exactly_the_finite_numbers(text):
    import argparse
    import math

    try:
        want = float(text)
    except ValueError:
        want = None
    if want is not None and math.isfinite(want):
        assert finite(text) == want
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            finite(text)


@pytest.mark.parametrize("flag, value, message", [
    ("--synth-seconds", "1e9", "--synth-seconds must be at most 3600 (one path), got 1e+09"),
    ("--speed", "1e6", "--speed must be at most 10 m/s, got 1e+06"),
    ("--speed", "-1", "--speed must be positive and finite, got -1"),
])
def test_synthesis_lengths_and_speeds_are_bounded(flag, value, message, tmp_path, capsys):
    assert main(["demo", "--run", str(tmp_path / "run"), f"{flag}={value}", "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"jaxstyle demo: error: {message}"
    assert not (tmp_path / "run" / "base").exists()  # refused before any training

"""canbench gen-trace refuses what would write a trace the bench then refuses (no frames) or
cannot write (a folder), on the command line, exit code 2."""
from __future__ import annotations

import pytest

from canbench import cli

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("args", [["--seconds", "0"], ["--seconds", "-1"], ["--seconds", "inf"],
                                  ["--kind", "burst", "--frames", "0"]])
def test_no_frames_is_refused_by_the_command_line(tmp_path, args):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["gen-trace", *args, "--out", str(tmp_path / "t.log")])
    assert exit_.value.code == 2 and not (tmp_path / "t.log").exists()


def test_a_span_too_short_for_a_frame_and_a_folder_are_refused(tmp_path, capsys):
    assert cli.main(["gen-trace", "--seconds", "0.001", "--out", str(tmp_path / "t.log")]) == 2
    assert capsys.readouterr().err == (f"canbench: {tmp_path / 't.log'}: not written: 0.001 s of powertrain traffic "
                                       "has no frame (give more)\n")
    assert cli.main(["gen-trace", "--out", str(tmp_path)]) == 2
    assert "is a folder: --out names the trace file" in capsys.readouterr().err

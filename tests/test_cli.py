"""The command line, as a newcomer runs it."""

from __future__ import annotations

import json

from adfusion.app.cli import main


def test_help_lists_the_commands(capsys):
    try:
        main(["--help"])
    except SystemExit as e:
        assert e.code == 0
    out = capsys.readouterr().out
    for cmd in ("detect", "solve", "simulate", "replay", "report", "demo", "bench", "catalog"):
        assert cmd in out


def test_help_imports_no_numpy():
    """``adfusion --help`` in a fresh interpreter loads neither numpy nor OpenCV."""
    import subprocess
    import sys

    code = ("import sys\nfrom adfusion.app.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numpy', 'cv2', 'scipy') if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60, check=True)
    assert p.stdout.strip().splitlines()[-1] == "[]"


def test_catalog_prints_renken_table(capsys):
    assert main(["catalog", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["sao"] for r in rows][-1] == 4480
    assert all(r["ours_V"] > 0 and r["ours_Hp"] > 0 for r in rows)
    assert main(["catalog"]) == 0
    assert "SAO" in capsys.readouterr().out


def test_solve_and_detect_the_builtin_example(capsys, tmp_path):
    assert main(["solve", "--example", "--json", "--overlay", str(tmp_path / "o.png")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] and res["error_vs_truth_arcsec"] < 10 and len(res["matches"]) >= 10
    assert (tmp_path / "o.png").stat().st_size > 10_000
    assert main(["detect", "--example", "--json"]) == 0
    det = json.loads(capsys.readouterr().out)
    assert det["truth_found"] >= 0.95 * det["truth_total"]


def test_errors_are_messages_not_tracebacks(capsys, tmp_path):
    assert main(["solve", str(tmp_path / "missing.png"), "--fov", "10"]) == 2
    assert "error" in capsys.readouterr().err
    assert main(["solve"]) == 2
    assert main(["simulate", "oedipus", "-o", str(tmp_path / "x.mcap"), "--duration", "0"]) == 2


def test_camera_and_fov_together_is_a_usage_error(capsys, tmp_path):
    """`--camera` silently won over `--fov` (new-user trial): both name the field of view,
    so giving both is exit 2 with a one-line message, in every command that takes them."""
    import cv2
    import numpy as np

    img = tmp_path / "f.png"
    cv2.imwrite(str(img), np.zeros((48, 64), np.uint8))
    cam = tmp_path / "cam.yaml"
    cam.write_text("not read: the flags are checked first\n")
    for argv in (["solve", str(img)], ["calibrate", str(img), "-o", str(tmp_path / "c.yaml")],
                 ["replay", str(img), "-o", str(tmp_path / "o.mcap")]):
        capsys.readouterr()
        assert main([*argv, "--camera", str(cam), "--fov", "10"]) == 2, argv
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert len(err) == 1 and "--camera or --fov, not both" in err[0], (argv, err)


def test_an_undecodable_image_is_one_line_on_stderr(tmp_path):
    """OpenCV's own log lines (`[ERROR:0@1.1] global grfmt_png.cpp …`) went to the terminal
    ahead of our message: a broken image is one line on the process's stderr, exit 2 (an
    input that cannot be used: nothing done)."""
    import os
    import subprocess
    import sys

    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\x0dIHDX" + bytes(40))
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_LOG_LEVEL"}
    p = subprocess.run([sys.executable, "-P", "-m", "adfusion.app.cli", "solve", str(bad),
                        "--fov", "10"], capture_output=True, text=True, timeout=120, env=env)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "broken.png" in lines[0], p.stderr


def test_a_wrong_flag_is_one_line_with_the_closest_flag():
    """argparse printed a 9-line usage block before the error, and a misspelt flag came
    from the top-level parser with no hint (new-user trial)."""
    import subprocess
    import sys

    run = [sys.executable, "-P", "-m", "adfusion.app.cli"]
    p = subprocess.run([*run, "solve", "x.tif", "--fovv", "11"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        "adfusion: error: unrecognized arguments: --fovv 11 (did you mean --fov?)"]
    p = subprocess.run([*run, "solve", "x.tif", "--fov-error", "-1"], capture_output=True,
                       text=True, timeout=60)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "--fov-error" in lines[0]
    assert "adfusion solve --help" in lines[0]


def test_a_wrong_field_of_view_gets_a_hint(shared_dir, capsys):
    """An 11.4° frame solved with --fov 20 said only "ambiguous: weak evidence … p_false 1"
    (new-user trial): a failure with nothing near an identification names the likely cause
    and the flag for an unknown lens."""
    frame = sorted((shared_dir / "data" / "real-images").glob("*.tiff"))[3]
    assert main(["solve", str(frame), "--fov", "20"]) == 1
    out = capsys.readouterr().out
    assert "hint:" in out and "--fov LO:HI" in out
    assert main(["solve", str(frame), "--fov", "11.4", "--fov-error", "0.5"]) == 0
    assert "hint:" not in capsys.readouterr().out


def test_outputs_never_overwrite_inputs_or_each_other(capsys, tmp_path):
    """`solve F --overlay F` replaced the input frame with its overlay, and `export LOG
    --csv LOG` turned the replayed log into a CSV (new-user trial): an output that names an
    input, or another output, is exit 2 with a one-line message, and nothing is written."""
    import cv2
    import numpy as np

    img = tmp_path / "f.png"
    cv2.imwrite(str(img), (np.arange(48 * 64).reshape(48, 64) % 251).astype(np.uint8))
    before = img.read_bytes()
    flight, log = tmp_path / "flight.mcap", tmp_path / "replay.mcap"
    assert main(["simulate", "oedipus", "-o", str(flight), "--duration", "1",
                 "--no-render"]) == 0
    assert main(["replay", str(flight), "-o", str(log)]) == 0
    log_bytes = log.read_bytes()
    aem = tmp_path / "a.aem"
    imu = tmp_path / "imu.csv"
    imu.write_text("t_s,gyro_x,gyro_y,gyro_z\n0.0,0,0,0\n")
    kept = {imu: imu.read_bytes()}
    for argv, why in (
            (["replay", str(flight), "-o", str(imu), "--imu", str(imu)], "is the input"),
            (["solve", str(img), "--fov", "10", "--overlay", str(img)], "is the input"),
            (["solve", str(img), "--fov", "10", "--overlay",
              str(tmp_path / "." / "f.png")], "is the input"),
            (["export", str(log), "--csv", str(log)], "is the input"),
            (["export", str(log), "--aem", str(log)], "is the input"),
            (["export", str(log), "--aem", str(aem), "--csv", str(aem)], "both name")):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert len(err) == 1 and why in err[0], (argv, err)
    assert img.read_bytes() == before and log.read_bytes() == log_bytes
    assert all(p.read_bytes() == b for p, b in kept.items())
    assert not aem.exists()


def test_a_rough_field_of_view_names_its_tolerance(shared_dir, capsys, tmp_path):
    """An 11.4° lens given as `--fov 12` solved 0 of 8 real frames with no hint in the
    batch summary, and `replay` of the folder ended "identified 0 (0.0 %)" with exit 0
    (new-user trial): both now say the tolerance flag, and the replay exits 1."""
    src = shared_dir / "data" / "real-images"
    frames = sorted(src.glob("*.tiff"))[:2]
    assert main(["solve", *map(str, frames), "--fov", "12"]) == 1
    out = capsys.readouterr().out
    assert "2 of 2 frames had nothing near an identification" in out and "--fov-error" in out
    assert main(["solve", str(frames[0]), "--fov", "12", "--fov-error", "1"]) == 0
    capsys.readouterr()
    times = tmp_path / "t.csv"
    times.write_text("filename,t_s\n" + "".join(f"{f.name},{k}\n" for k, f in
                                                enumerate(sorted(src.glob("*.tiff")))))
    out_log = tmp_path / "o.mcap"
    assert main(["replay", str(src), "-o", str(out_log), "--fov", "12",
                 "--timestamps", str(times)]) == 1
    err = capsys.readouterr().err
    assert "no frame of 8 was identified" in err and "--fov-error" in err
    assert out_log.exists()  # the output is written either way


def test_a_fov_error_beyond_the_field_of_view_names_the_flag(capsys, tmp_path):
    """``--fov-error 6`` with a 5.7° lens said "fov_error_deg must be in [0, 5.70)": the
    Python parameter, exit 1. It is the flag's usage error, with the fix."""
    import cv2
    import numpy as np

    img = tmp_path / "f.png"
    cv2.imwrite(str(img), np.zeros((48, 64), np.uint8))
    assert main(["solve", str(img), "--fov", "5.7", "--fov-error", "6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fov-error 6: must be below the camera's 5.7°" in err[0]
    assert "fov_error_deg" not in err[0] and "--fov LO:HI" in err[0]


def test_every_option_has_help_and_says_its_default():
    """``--method`` had no help, ``--sigma`` did not say its default (new-user trial)."""
    import argparse
    import re

    from adfusion.app.cli import build_parser

    def walk(parser, path):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, [*path, name])
            elif not isinstance(a, argparse._HelpAction):
                yield " ".join(path), a

    found = list(walk(build_parser(bench=True), []))
    assert len(found) > 100
    no_help = [(cmd, a.dest) for cmd, a in found if not a.help or a.help == argparse.SUPPRESS]
    assert no_help == []
    silent = [(cmd, a.dest) for cmd, a in found
              if a.option_strings and a.default not in (None, False, True, argparse.SUPPRESS)
              and "default" not in a.help]
    assert silent == []
    # an option without a default says what happens without it (the flags of a folder
    # replay did not: --fps, --timestamps, --start-utc, --mount, --imu)
    unsaid = [(cmd, a.dest) for cmd, a in found
              if a.option_strings and a.default is None and a.nargs != 0 and not a.required
              and not re.search(r"\b(default|without)\b", a.help, re.IGNORECASE)]
    assert unsaid == []
    import subprocess
    import sys

    for cmd in ("solve", "replay", "calibrate", "simulate", "bench starid"):  # help renders
        p = subprocess.run([sys.executable, "-m", "adfusion", *cmd.split(), "--help"],
                           capture_output=True, text=True, timeout=60)
        assert p.returncode == 0 and "default" in p.stdout, (cmd, p.stderr)


def test_a_closed_pipe_keeps_the_exit_status(tmp_path):
    """``adfusion solve FRAME | head -0`` exited 0 for a frame that was not identified: the
    write that met the closed pipe ended the command before its own status (issue 33)."""
    import subprocess
    import sys

    import cv2
    import numpy as np

    noise = tmp_path / "noise.png"
    cv2.imwrite(str(noise), np.random.default_rng(3).integers(0, 30, (96, 128), np.uint8))
    for argv, want in ((["solve", str(noise), "--fov", "10"], 1),
                       (["solve", "--example"], 0), (["topics"], 0)):
        p = subprocess.Popen([sys.executable, "-m", "adfusion", *argv],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        p.stdout.close()  # the reader is gone before the first line
        err = p.stderr.read().decode()
        assert p.wait(timeout=120) == want, (argv, err)
        assert "Traceback" not in err and "BrokenPipe" not in err

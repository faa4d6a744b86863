"""The README's main command on a CPU: the quickstart continues the shipped flat policy, says so,
and reaches goals (shortened to 3,200 env steps here; the README's run is 9,600)."""

import re


def test_cpu_quickstart_starts_from_the_flat_policy_and_reaches_goals(tmp_path, capsys):
    from train.cli import main

    assert (
        main(
            [
                "--run-dir",
                str(tmp_path / "quick"),
                "--set",
                "run.num_timesteps=3200",
                "--set",
                "run.checkpoint_every=3200",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert f"run dir: {tmp_path / 'quick'}" in out.splitlines()[0]  # printed before anything compiles
    assert re.search(r"starting from the policy network and observation statistics of the policy file \S*flat", out)
    success = float(re.search(r"episode/success_rate: (\S+)", out).group(1))
    assert success > 0.5, out[-2000:]
    assert (tmp_path / "quick" / "learning_curve.png").is_file()

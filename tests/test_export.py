"""Policy export: the numpy and ONNX policies against the JAX policy, the file format's checks, the CLI."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hsa_mjx.deploy import policy_file
from train import config as train_config
from train import export

ATOL = 1e-5
N_OBS, N_ACT = 24, 8  # the default observation (no optional entries) and the 8 servos


def random_training_state(config: train_config.TrainConfig, seed: int = 0):
    """(networks, TrainingState) with random weights, biases and observation statistics."""
    import jax
    import jax.numpy as jnp

    from train.learners.ppo.networks import init_training_state, make_networks

    networks = make_networks(config, N_OBS, N_ACT)
    ts = init_training_state(config, networks, jax.random.PRNGKey(seed), N_OBS)
    rng = np.random.default_rng(seed)

    def noisy(x):
        return jnp.asarray(np.asarray(x) + 0.3 * rng.normal(size=np.shape(x)), jnp.float32)

    normalizer = ts.normalizer.replace(
        mean=jnp.asarray(rng.normal(size=N_OBS) * 2.0, jnp.float32),
        std=jnp.asarray(rng.uniform(0.05, 3.0, size=N_OBS), jnp.float32),
    )
    return networks, ts.replace(
        params=ts.params.replace(policy=jax.tree.map(noisy, ts.params.policy)), normalizer=normalizer
    )


def observations(policy: policy_file.NumpyPolicy, n: int = 100, seed: int = 1) -> np.ndarray:
    """Observations around the normaliser's mean, many far enough out to hit the observation clip."""
    rng = np.random.default_rng(seed)
    return (policy.params["obs_mean"] + policy.params["obs_std"] * rng.normal(size=(n, N_OBS)) * 6.0).astype(np.float32)


def jax_actions(networks, ts, obs: np.ndarray) -> np.ndarray:
    """The Brax policy's deterministic actions (as train.evaluate runs it)."""
    import jax
    from brax.training.agents.ppo import networks as ppo_networks

    policy = ppo_networks.make_inference_fn(networks)((ts.normalizer, ts.params.policy), deterministic=True)
    return np.asarray(jax.jit(policy)(obs, jax.random.PRNGKey(0))[0])


def onnx_actions(directory, obs: np.ndarray) -> np.ndarray:
    """Actions of an exported ``policy.onnx`` run with onnxruntime."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(directory / export.ONNX_FILE), providers=["CPUExecutionProvider"])
    return session.run(["action"], {"observation": obs})[0]


def export_both(policy: policy_file.NumpyPolicy, tmp_path) -> tuple[policy_file.NumpyPolicy, object]:
    """Write ``policy`` as npz and onnx; return (the npz loaded back, the onnx directory)."""
    export.write(policy, tmp_path / "npz", "npz")
    export.write(policy, tmp_path / "onnx", "onnx")
    return policy_file.load_policy(tmp_path / "npz"), tmp_path / "onnx"


@pytest.mark.parametrize("distribution", train_config.DISTRIBUTIONS)
@pytest.mark.parametrize("activation", train_config.ACTIVATIONS)
def test_exported_policies_match_the_jax_policy(activation, distribution, tmp_path):
    config = train_config.from_dict(
        {
            "ppo": {
                "activation": activation,
                "distribution_type": distribution,
                "observation_clip": 5.0,
                "policy_hidden_sizes": [16, 12],
            }
        }
    )
    networks, ts = random_training_state(config)
    policy, onnx_dir = export_both(export.to_numpy_policy(config, ts, {"run": "random"}), tmp_path)
    obs = observations(policy)
    normalized = (obs - policy.params["obs_mean"]) / policy.params["obs_std"]
    assert np.mean(np.abs(normalized) > 5.0) > 0.2  # the clip is exercised
    want = jax_actions(networks, ts, obs)
    assert np.std(want) > 0.1 and (distribution == "normal" or np.max(np.abs(want)) <= 1.0)
    np.testing.assert_allclose(policy(obs), want, atol=ATOL, rtol=0)
    np.testing.assert_allclose(onnx_actions(onnx_dir, obs), want, atol=ATOL, rtol=0)
    np.testing.assert_allclose(policy(obs[3]), want[3], atol=ATOL, rtol=0)  # one observation
    assert policy.meta["network"]["output"] == ("tanh" if distribution == "tanh_normal" else "identity")
    assert train_config.from_dict(policy.meta["config"]) == config  # the env and networks can be rebuilt


def test_export_without_observation_normalisation(tmp_path):
    config = train_config.from_dict(
        {"ppo": {"normalize_observations": False, "observation_clip": 5.0, "policy_hidden_sizes": [16]}}
    )
    networks, ts = random_training_state(config)
    policy, onnx_dir = export_both(export.to_numpy_policy(config, ts, {}), tmp_path)
    assert policy.meta["network"]["observation_clip"] == 0.0  # Brax applies no clip without the normaliser
    np.testing.assert_array_equal(policy.params["obs_mean"], 0.0)
    obs = np.random.default_rng(2).normal(size=(100, N_OBS)).astype(np.float32) * 3.0
    want = jax_actions(networks, ts, obs)
    np.testing.assert_allclose(policy(obs), want, atol=ATOL, rtol=0)
    np.testing.assert_allclose(onnx_actions(onnx_dir, obs), want, atol=ATOL, rtol=0)


def test_export_cli_on_a_trained_run(tiny_run_dir, tmp_path, capsys):
    from train.run import checkpoint
    from train.run.saved import load_training_state

    for fmt in export.FORMATS:
        assert export.main([str(tiny_run_dir), "--format", fmt, "--out", str(tmp_path / fmt)]) == 0
    assert "env steps" in capsys.readouterr().out
    latest = checkpoint.latest(tiny_run_dir)
    config = train_config.from_dict(checkpoint.read_meta(latest)["config"])
    networks, ts = load_training_state(config, latest, N_OBS, N_ACT)
    policy = policy_file.load_policy(tmp_path / "npz")
    # observations as the env gives them, within 3 normaliser stds: the tiny run's stds are tiny in
    # some slots, and raw N(0, 3) values there normalise to thousands, where float32 sums in numpy's
    # and XLA's orders differ by more than the bound (1.6e-5 seen) for reasons the export cannot change
    z = np.random.default_rng(3).normal(size=(100, N_OBS)) * 3.0
    obs = (policy.params["obs_mean"] + policy.params["obs_std"] * z).astype(np.float32)
    want = jax_actions(networks, ts, obs)
    np.testing.assert_allclose(policy(obs), want, atol=ATOL, rtol=0)
    np.testing.assert_allclose(onnx_actions(tmp_path / "onnx", obs), want, atol=ATOL, rtol=0)
    source = policy.meta["source"]
    assert source["step"] == source["env_steps"] == int(latest.name.split("_")[1]) >= 80
    assert source["checkpoint"] == latest.name and "--format npz" in source["command"]  # outside the cwd: its name
    assert not Path(source["run"]).is_absolute()  # no machine's absolute path in a result file
    assert train_config.from_dict(policy.meta["config"]) == config
    assert json.loads((tmp_path / "onnx" / policy_file.META_FILE).read_text())["network"] == policy.meta["network"]


def corrupt_copies(run_dir, root):
    """Copies of a run's latest checkpoint, each broken in one way, with the expected error text."""
    from train.run import checkpoint

    latest = checkpoint.latest(run_dir)
    meta = json.loads((latest / checkpoint.META_FILE).read_text())
    cases = {}

    def copy(name, edit_meta=None, state=None, meta_text=None):
        target = root / name / "checkpoints" / latest.name
        shutil.copytree(latest, target)
        if edit_meta is not None:
            changed = json.loads(json.dumps(meta))
            edit_meta(changed)
            (target / checkpoint.META_FILE).write_text(json.dumps(changed))
        if meta_text is not None:
            (target / checkpoint.META_FILE).write_text(meta_text)
        if state is not None:
            (target / checkpoint.STATE_FILE).write_bytes(state)
        return root / name

    cases["not valid JSON"] = copy("bad_meta", meta_text="{not json")
    cases["cannot be decoded"] = copy("bad_state", state=b"\xc1garbage")
    cases["does not match this config"] = copy("wider", lambda m: m["config"]["ppo"].update(policy_hidden_sizes=[16]))
    cases["unknown config key"] = copy("unknown_key", lambda m: m["config"]["ppo"].update(nope=1))
    cases["unsupported or corrupt metadata"] = copy("format", lambda m: m.update(format=99))
    (root / "empty").mkdir()
    cases["no checkpoint found"] = root / "empty"
    cases["run directory not found"] = root / "missing"
    return cases


def test_export_refuses_corrupt_or_incompatible_runs(tiny_run_dir, tmp_path, capsys):
    for expected, run in corrupt_copies(tiny_run_dir, tmp_path / "runs").items():
        out = tmp_path / "out" / run.name
        assert export.main([str(run), "--format", "npz", "--out", str(out)]) == 2, expected
        assert expected in capsys.readouterr().err, expected
        assert not out.exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("not a policy")
    assert export.main([str(tiny_run_dir), "--format", "onnx", "--out", str(busy)]) == 2
    assert "not a policy directory" in capsys.readouterr().err
    assert sorted(p.name for p in busy.iterdir()) == ["notes.txt"]
    with pytest.raises(SystemExit):  # argparse: an unknown format
        export.main([str(tiny_run_dir), "--format", "pt"])


def small_policy(tmp_path, name="p", hidden=(5,)) -> policy_file.NumpyPolicy:
    """A hand-made policy written with the numpy-only writer (no JAX involved)."""
    rng = np.random.default_rng(4)
    sizes = [N_OBS, *hidden, N_ACT]
    params = {
        "obs_mean": rng.normal(size=N_OBS),
        "obs_std": rng.uniform(0.5, 2.0, size=N_OBS),
        "kernels": tuple(rng.normal(size=(a, b)) for a, b in zip(sizes[:-1], sizes[1:])),
        "biases": tuple(rng.normal(size=b) for b in sizes[1:]),
    }
    meta = policy_file.describe(params, "elu", "tanh_normal", 3.0, [f"o{i}" for i in range(N_OBS)])
    policy_file.save_policy(tmp_path / name, params, {**meta, "config": {}, "source": {}})
    return policy_file.load_policy(tmp_path / name)


def test_policy_round_trip_and_numpy_forward(tmp_path):
    policy = small_policy(tmp_path)
    assert all(a.dtype == np.float32 for a in policy_file.flatten(policy.params).values())
    obs = observations(policy, 10)
    x = np.clip((obs - policy.params["obs_mean"]) / policy.params["obs_std"], -3.0, 3.0)
    hidden = x @ policy.params["kernels"][0] + policy.params["biases"][0]
    hidden = np.where(hidden > 0, hidden, np.exp(hidden) - 1.0)
    want = np.tanh(hidden @ policy.params["kernels"][1] + policy.params["biases"][1])
    np.testing.assert_allclose(policy(obs), want, atol=1e-6)
    assert policy(obs[0]).shape == (N_ACT,) and policy(obs).shape == (10, N_ACT)
    with pytest.raises(ValueError, match=r"observation must have shape \(24,\)"):
        policy(np.zeros(N_OBS + 1))
    small_policy(tmp_path, hidden=(7, 7))  # re-export over an existing policy directory replaces it
    assert len(policy_file.load_policy(tmp_path / "p").params["kernels"]) == 3


def test_policy_loader_refuses_bad_files(tmp_path):
    good = small_policy(tmp_path)
    meta = json.loads((tmp_path / "p" / policy_file.META_FILE).read_text())
    arrays = policy_file.flatten(good.params)

    def variant(name, meta_text=None, npz=None):
        shutil.copytree(tmp_path / "p", tmp_path / name)
        if meta_text is not None:
            (tmp_path / name / policy_file.META_FILE).write_text(meta_text)
        if npz is not None:
            np.savez(tmp_path / name / policy_file.WEIGHTS_FILE, **npz)
        return tmp_path / name

    cases = {
        "not valid JSON": variant("json", meta_text="{"),
        "format version 2": variant("version", meta_text=json.dumps({**meta, "format_version": 2})),
        "dense_0_kernel has float32 (5, 24)": variant(
            "shape", npz={**arrays, "dense_0_kernel": arrays["dense_0_kernel"].T}
        ),
        "obs_std has float64": variant("dtype", npz={**arrays, "obs_std": arrays["obs_std"].astype(np.float64)}),
        "lacks array(s) ['dense_1_bias']": variant(
            "missing", npz={k: v for k, v in arrays.items() if k != "dense_1_bias"}
        ),
        "holds NaN": variant("nan", npz={**arrays, "dense_1_bias": np.full(N_ACT, np.nan, np.float32)}),
        "cannot be read": variant("pickle", npz={**arrays, "obs_mean": np.array([{"a": 1}], dtype=object)}),
    }
    for expected, directory in cases.items():
        with pytest.raises(ValueError, match=expected.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
            policy_file.load_policy(directory)
    (variant("garbage") / policy_file.WEIGHTS_FILE).write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match="garbage/policy.npz is corrupt"):
        policy_file.load_policy(tmp_path / "garbage")
    (variant("no_npz") / policy_file.WEIGHTS_FILE).unlink()
    with pytest.raises(FileNotFoundError, match="no_npz/policy.npz"):
        policy_file.load_policy(tmp_path / "no_npz")
    with pytest.raises(FileNotFoundError, match="policy directory not found"):
        policy_file.load_policy(tmp_path / "nowhere")


def test_numpy_policy_loads_and_runs_without_jax(tmp_path):
    small_policy(tmp_path)
    code = (
        f"import sys, numpy as np\nfrom hsa_mjx.deploy.policy_file import load_policy\n"
        f"p = load_policy({str(tmp_path / 'p')!r})\n"
        f"assert p(np.zeros({N_OBS})).shape == ({N_ACT},) and p(np.zeros((3, {N_OBS}))).shape == (3, {N_ACT})\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'brax', 'flax', 'mujoco'))\n"
        "assert not heavy, heavy\nprint('ok')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parent.parent,
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


SHIPPED = sorted(p.parent.name for p in Path("policies").glob(f"*/{policy_file.META_FILE}"))


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_policy_folder_converts_to_onnx_with_the_same_actions(name, tmp_path, capsys):
    """``python -m train.export policies/NAME --format onnx``: the documented bound, 1e-5, holds for
    observations within 10 standard deviations of the normaliser's mean (arbitrary values far
    outside it round differently in float32: docs/policies.md)."""
    policy = policy_file.load_policy(Path("policies") / name)
    assert export.main([f"policies/{name}", "--format", "onnx", "--out", str(tmp_path / "onnx")]) == 0
    meta = json.loads((tmp_path / "onnx" / policy_file.META_FILE).read_text())
    assert meta["source"]["converted_from"] == f"policies/{name}" and meta["observation"] == policy.meta["observation"]
    rng = np.random.default_rng(0)
    scale = rng.uniform(-10, 10, size=(200, policy.observation_size))
    obs = (policy.params["obs_mean"] + scale * policy.params["obs_std"]).astype(np.float32)
    np.testing.assert_allclose(onnx_actions(tmp_path / "onnx", obs), policy(obs), atol=1e-5, rtol=0)
    assert (
        export.main([f"policies/{name}", "--format", "onnx", "--checkpoint", "x", "--out", str(tmp_path / "again")])
        == 2
    )
    assert "policy directory holds one policy" in capsys.readouterr().err

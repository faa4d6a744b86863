"""The deterministic policy of ``hsa_mjx.deploy.policy_file`` as an ONNX graph (normaliser, clip, MLP, output squash).

Built with the ``onnx`` package's helper API from the same float32 arrays as ``policy.npz``
(initializers named as the npz keys). Input ``observation`` (batch, obs), output ``action``
(batch, action), the batch dimension symbolic. Opset 17 and IR version 8: supported by
onnxruntime since 1.13 and by the common deployment runtimes (TensorRT, OpenVINO); every op used
(Sub, Div, Clip, MatMul, Add, Sigmoid, Mul, Tanh, Relu, Elu) has been in ONNX since opset 11 or earlier.
"""

from __future__ import annotations

import numpy as np

from hsa_mjx.deploy import policy_file

OPSET, IR_VERSION = 17, 8
INPUT, OUTPUT = "observation", "action"


def _activation(nodes: list, x: str, name: str, prefix: str) -> str:
    """Append the nodes of one activation (flax's definitions) and return its output name."""
    from onnx import helper

    out = f"{prefix}_{name}"
    if name == "swish":  # x * sigmoid(x)
        nodes += [
            helper.make_node("Sigmoid", [x], [f"{prefix}_sigmoid"]),
            helper.make_node("Mul", [x, f"{prefix}_sigmoid"], [out]),
        ]
    elif name in ("tanh", "relu"):
        nodes.append(helper.make_node(name.capitalize(), [x], [out]))
    elif name == "elu":
        nodes.append(helper.make_node("Elu", [x], [out], alpha=1.0))
    else:
        raise ValueError(f"unknown activation {name!r}; choose one of {list(policy_file.ACTIVATIONS)}")
    return out


def _normalizer(nodes: list, inits: dict, params: dict, clip: float) -> str:
    """(obs - obs_mean) / obs_std, clipped to +-clip when clip > 0; returns the output name."""
    from onnx import helper

    inits["obs_mean"], inits["obs_std"] = params["obs_mean"], params["obs_std"]
    nodes += [
        helper.make_node("Sub", [INPUT, "obs_mean"], ["centred"]),
        helper.make_node("Div", ["centred", "obs_std"], ["normalized"]),
    ]
    if clip <= 0:
        return "normalized"
    inits["clip_min"], inits["clip_max"] = np.float32(-clip), np.float32(clip)
    nodes.append(helper.make_node("Clip", ["normalized", "clip_min", "clip_max"], ["clipped"]))
    return "clipped"


def build(policy: policy_file.NumpyPolicy):
    """The ONNX ``ModelProto`` computing ``policy``'s deterministic action (checked with onnx.checker)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    net, params = policy.meta["network"], policy.params
    nodes: list = []
    inits: dict[str, np.ndarray] = {}
    x = _normalizer(nodes, inits, params, float(net["observation_clip"]))
    layers = policy_file.layer_names(len(params["kernels"]))
    for i, ((k, b), kernel, bias) in enumerate(zip(layers, params["kernels"], params["biases"])):
        inits[k], inits[b] = kernel, bias
        nodes += [
            helper.make_node("MatMul", [x, k], [f"dense_{i}_matmul"]),
            helper.make_node("Add", [f"dense_{i}_matmul", b], [f"dense_{i}_out"]),
        ]
        x = f"dense_{i}_out"
        if i < len(layers) - 1:
            x = _activation(nodes, x, net["activation"], f"dense_{i}")
    nodes.append(helper.make_node("Tanh" if net["output"] == "tanh" else "Identity", [x], [OUTPUT]))
    graph = helper.make_graph(
        nodes,
        "hsa_mjx_policy",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["batch", policy.observation_size])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["batch", policy.action_size])],
        initializer=[numpy_helper.from_array(np.asarray(v, np.float32), name) for name, v in inits.items()],
    )
    model = helper.make_model(
        graph,
        producer_name="hsa_mjx",
        opset_imports=[helper.make_opsetid("", OPSET)],
        ir_version=IR_VERSION,
        doc_string=net["deterministic_action"],
    )
    onnx.checker.check_model(model, full_check=True)
    return model

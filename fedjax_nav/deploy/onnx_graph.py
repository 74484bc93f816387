"""The exported actor as an ONNX graph (`fedjax-nav export --format onnx`), built from exactly the
arrays written to weights.npz (fedjax_nav.deploy.export).

Why the ONNX graph is written with the `onnx` package's helper API and not with jax2onnx:
jax2onnx 0.17.1 (the newest on PyPI) does export this actor (checked in an isolated directory:
Gemm / Max / Sigmoid / Tanh / Concat, max |diff| 3e-7 against flax), but it requires
orbax-checkpoint < 0.11.37 while this project runs orbax-checkpoint 0.12.8 (checkpoints), and it
pulls about 25 further packages (huggingface-hub, netron, equinox, dm-pix, orbax-export, ...);
the newest release compatible with orbax 0.12.8 is the older 0.13.0 with the same dependency
tree. The actor is a handful of Gemm + activation nodes, so the graph is built here from exactly
the arrays written to weights.npz (needs only `onnx`, a light dependency; checked with
onnxruntime in tests/test_export.py). tf2onnx was not considered (it pulls TensorFlow).
"""

from __future__ import annotations

import json

import numpy as np

from fedjax_nav.deploy.policy_template import INPUT_LAYER  # the layer whose kernel's rows are the observation

ONNX_OPSET = 17  # Gemm, Relu, Tanh, Sigmoid, Elu, Mul, Add, Concat, Sub, Div, Clip: runtimes from 2022 on read it
ONNX_IR_VERSION = 8  # the IR version of opset 17 (onnx would stamp its newest, which older runtimes refuse)


def onnx_model(weights: dict[str, np.ndarray], activation: str, metadata: dict | None = None, kind: str = "heads"):
    """The actor as an onnx.ModelProto: input "obs" float32[batch, obs_size], output "action"
    float32[batch, 2]. kind "heads": concat(sigmoid(v_head(x)), tanh(omega_head(x))), x = the
    hidden stack; "squashed": loc + scale * tanh(mean(x)) (box loc (0.5, 0), scale (0.5, 1));
    "gru": also input "h" float32[batch, gru] (zeros at an episode's start) and output "h_out"
    (the state after this step, to feed back as "h"), the layers of policy_template.gru_forward.
    Weights with an observation normaliser ("obs_norm/*") first take clip((obs - mean) / std),
    as policy_template.normalize_input."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if kind not in INPUT_LAYER:
        raise ValueError(f"unknown network kind {kind!r}")
    depth = sum(1 for k in weights if k.startswith("hidden_") and k.endswith("/kernel"))
    obs_size = int(weights[f"{INPUT_LAYER[kind]}/kernel"].shape[0])
    inits, nodes = [], []

    def const(name, value):
        inits.append(numpy_helper.from_array(np.asarray(value, np.float32), name))
        return name

    def gemm(x, prefix, out):
        w = const(f"{prefix}.kernel", weights[f"{prefix}/kernel"])
        if f"{prefix}/bias" not in weights:  # the GRU's recurrent gates have no bias
            nodes.append(helper.make_node("MatMul", [x, w], [out], name=f"{prefix}.matmul"))
            return out
        b = const(f"{prefix}.bias", weights[f"{prefix}/bias"])
        nodes.append(helper.make_node("Gemm", [x, w, b], [out], name=f"{prefix}.gemm"))
        return out

    def node(op, ins, out):
        nodes.append(helper.make_node(op, ins, [out]))
        return out

    def act(x, i):
        out = f"h{i}" if isinstance(i, int) else i
        if activation == "relu":
            nodes.append(helper.make_node("Relu", [x], [out]))
        elif activation == "tanh":
            nodes.append(helper.make_node("Tanh", [x], [out]))
        elif activation == "elu":
            nodes.append(helper.make_node("Elu", [x], [out], alpha=1.0))
        elif activation == "silu":  # x * sigmoid(x)
            nodes.append(helper.make_node("Sigmoid", [x], [f"{x}.sig"]))
            nodes.append(helper.make_node("Mul", [x, f"{x}.sig"], [out]))
        elif activation == "gelu":  # flax's gelu: the tanh approximation, spelled out (Gelu is opset 20)
            c = const(f"{x}.c", np.sqrt(2.0 / np.pi))
            k = const(f"{x}.k", 0.044715)
            half, one = const(f"{x}.half", 0.5), const(f"{x}.one", 1.0)
            n = lambda op, ins, o: nodes.append(helper.make_node(op, ins, [o]))  # noqa: E731
            n("Mul", [x, x], f"{x}.x2")
            n("Mul", [f"{x}.x2", x], f"{x}.x3")
            n("Mul", [k, f"{x}.x3"], f"{x}.kx3")
            n("Add", [x, f"{x}.kx3"], f"{x}.inner")
            n("Mul", [c, f"{x}.inner"], f"{x}.arg")
            n("Tanh", [f"{x}.arg"], f"{x}.t")
            n("Add", [one, f"{x}.t"], f"{x}.1t")
            n("Mul", [half, f"{x}.1t"], f"{x}.cdf")
            n("Mul", [x, f"{x}.cdf"], out)
        else:
            raise ValueError(f"unknown activation {activation!r}")
        return out

    def squash_into_box(mean):  # loc + scale * tanh(mean): the squashed Gaussian's mode
        t = node("Tanh", [mean], f"{mean}.tanh")
        scaled = node("Mul", [const("box.scale", [[0.5, 1.0]]), t], f"{mean}.scaled")
        return node("Add", [const("box.loc", [[0.5, 0.0]]), scaled], "action")

    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_size])]
    outputs = [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])]
    x = "obs"
    if "obs_norm/mean" in weights:  # policy_template.normalize_input
        c = float(weights["obs_norm/clip"])
        z = node(
            "Div",
            [
                node("Sub", ["obs", const("obs_norm.mean", weights["obs_norm/mean"])], "obs.centred"),
                const("obs_norm.std", weights["obs_norm/std"]),
            ],
            "obs.scaled",
        )
        x = node("Clip", [z, const("obs_norm.low", -c), const("obs_norm.high", c)], "obs.norm")
    if kind == "gru":  # flax's GRUCell, as policy_template.gru_cell
        gru = int(weights["gru/hn/kernel"].shape[0])
        inputs.append(helper.make_tensor_value_info("h", TensorProto.FLOAT, ["batch", gru]))
        outputs.append(helper.make_tensor_value_info("h_out", TensorProto.FLOAT, ["batch", gru]))
        x = act(gemm(x, "embed", "embed.z"), "embed.out")
        r_pre = node("Add", [gemm(x, "gru/ir", "ir"), gemm("h", "gru/hr", "hr")], "r.pre")
        z_pre = node("Add", [gemm(x, "gru/iz", "iz"), gemm("h", "gru/hz", "hz")], "z.pre")
        r, z = node("Sigmoid", [r_pre], "r"), node("Sigmoid", [z_pre], "z")
        rh = node("Mul", [r, gemm("h", "gru/hn", "hn")], "r.hn")
        n = node("Tanh", [node("Add", [gemm(x, "gru/in", "in"), rh], "n.pre")], "n")
        one_minus_z = node("Sub", [const("gru.one", 1.0), z], "1-z")
        x = node("Add", [node("Mul", [one_minus_z, n], "(1-z)n"), node("Mul", [z, "h"], "zh")], "h_out")
    for i in range(depth):
        x = act(gemm(x, f"hidden_{i}", f"z{i}"), i)
    if kind == "heads":
        gemm(x, "v_head", "v_pre")
        gemm(x, "omega_head", "omega_pre")
        nodes.append(helper.make_node("Sigmoid", ["v_pre"], ["v"]))
        nodes.append(helper.make_node("Tanh", ["omega_pre"], ["omega"]))
        nodes.append(helper.make_node("Concat", ["v", "omega"], ["action"], axis=1))
    else:
        squash_into_box(gemm(x, "mean" if kind == "squashed" else "head", "mean_pre"))
    graph = helper.make_graph(nodes, "fedjax_nav_actor", inputs, outputs, initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", ONNX_OPSET)], producer_name="fedjax_nav")
    model.ir_version = ONNX_IR_VERSION
    model.doc_string = (
        f"fedjax_nav greedy actor ({kind}): obs = (ranges[num_beams] m, goal distance m, goal bearing rad, "
        "previous action) -> action = (v / v_max, omega / omega_max)"
        + ("; h: the GRU state (zeros at an episode's start), h_out: the next one" if kind == "gru" else "")
    )
    for key, value in (metadata or {}).items():
        entry = model.metadata_props.add()
        entry.key, entry.value = str(key), value if isinstance(value, str) else json.dumps(value)
    onnx.checker.check_model(model)
    return model

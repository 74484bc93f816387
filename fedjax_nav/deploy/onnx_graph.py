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
    from onnx import TensorProto, helper

    if kind not in INPUT_LAYER:
        raise ValueError(f"unknown network kind {kind!r}")
    depth = sum(1 for k in weights if k.startswith("hidden_") and k.endswith("/kernel"))
    obs_size = int(weights[f"{INPUT_LAYER[kind]}/kernel"].shape[0])
    g = _Graph(weights, activation)
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_size])]
    outputs = [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])]
    x = _normalized_input(g, "obs")
    if kind == "gru":
        gru = int(weights["gru/hn/kernel"].shape[0])
        inputs.append(helper.make_tensor_value_info("h", TensorProto.FLOAT, ["batch", gru]))
        outputs.append(helper.make_tensor_value_info("h_out", TensorProto.FLOAT, ["batch", gru]))
        x = _gru_layers(g, x)
    for i in range(depth):
        x = g.act(g.gemm(x, f"hidden_{i}", f"z{i}"), i)
    _action_head(g, x, kind)
    graph = helper.make_graph(g.nodes, "fedjax_nav_actor", inputs, outputs, initializer=g.inits)
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


class _Graph:
    """The initializers and nodes of the graph being built, in the order they are added, and the
    ops that add them (from the export's weights, named by their weights.npz keys)."""

    def __init__(self, weights: dict[str, np.ndarray], activation: str):
        from onnx import helper, numpy_helper

        self.helper, self.numpy_helper = helper, numpy_helper
        self.weights, self.activation = weights, activation
        self.inits, self.nodes = [], []

    def const(self, name, value):
        self.inits.append(self.numpy_helper.from_array(np.asarray(value, np.float32), name))
        return name

    def gemm(self, x, prefix, out):
        w = self.const(f"{prefix}.kernel", self.weights[f"{prefix}/kernel"])
        if f"{prefix}/bias" not in self.weights:  # the GRU's recurrent gates have no bias
            self.nodes.append(self.helper.make_node("MatMul", [x, w], [out], name=f"{prefix}.matmul"))
            return out
        b = self.const(f"{prefix}.bias", self.weights[f"{prefix}/bias"])
        self.nodes.append(self.helper.make_node("Gemm", [x, w, b], [out], name=f"{prefix}.gemm"))
        return out

    def node(self, op, ins, out, **attrs):
        self.nodes.append(self.helper.make_node(op, ins, [out], **attrs))
        return out

    def act(self, x, i):
        out = f"h{i}" if isinstance(i, int) else i
        if self.activation == "relu":
            self.node("Relu", [x], out)
        elif self.activation == "tanh":
            self.node("Tanh", [x], out)
        elif self.activation == "elu":
            self.node("Elu", [x], out, alpha=1.0)
        elif self.activation == "silu":  # x * sigmoid(x)
            self.node("Sigmoid", [x], f"{x}.sig")
            self.node("Mul", [x, f"{x}.sig"], out)
        elif self.activation == "gelu":  # flax's gelu: the tanh approximation, spelled out (Gelu is opset 20)
            c = self.const(f"{x}.c", np.sqrt(2.0 / np.pi))
            k = self.const(f"{x}.k", 0.044715)
            half, one = self.const(f"{x}.half", 0.5), self.const(f"{x}.one", 1.0)
            n = self.node
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
            raise ValueError(f"unknown activation {self.activation!r}")
        return out


def _normalized_input(g: _Graph, x: str) -> str:
    """clip((obs - mean) / std, -clip, clip) with the weights' observation normaliser
    (policy_template.normalize_input); `x` itself without one."""
    w = g.weights
    if "obs_norm/mean" not in w:
        return x
    c = float(w["obs_norm/clip"])
    z = g.node(
        "Div",
        [
            g.node("Sub", [x, g.const("obs_norm.mean", w["obs_norm/mean"])], "obs.centred"),
            g.const("obs_norm.std", w["obs_norm/std"]),
        ],
        "obs.scaled",
    )
    return g.node("Clip", [z, g.const("obs_norm.low", -c), g.const("obs_norm.high", c)], "obs.norm")


def _gru_layers(g: _Graph, x: str) -> str:
    """The embedding and flax's GRUCell on input "h", as policy_template.gru_cell; returns "h_out"."""
    node, gemm = g.node, g.gemm
    x = g.act(gemm(x, "embed", "embed.z"), "embed.out")
    r_pre = node("Add", [gemm(x, "gru/ir", "ir"), gemm("h", "gru/hr", "hr")], "r.pre")
    z_pre = node("Add", [gemm(x, "gru/iz", "iz"), gemm("h", "gru/hz", "hz")], "z.pre")
    r, z = node("Sigmoid", [r_pre], "r"), node("Sigmoid", [z_pre], "z")
    rh = node("Mul", [r, gemm("h", "gru/hn", "hn")], "r.hn")
    n = node("Tanh", [node("Add", [gemm(x, "gru/in", "in"), rh], "n.pre")], "n")
    one_minus_z = node("Sub", [g.const("gru.one", 1.0), z], "1-z")
    return node("Add", [node("Mul", [one_minus_z, n], "(1-z)n"), node("Mul", [z, "h"], "zh")], "h_out")


def _action_head(g: _Graph, x: str, kind: str) -> str:
    """ "action" from the hidden stack's output: the sigmoid and tanh heads ("heads"), or the
    squashed Gaussian's mode loc + scale * tanh(mean) in the action box."""
    if kind == "heads":
        g.gemm(x, "v_head", "v_pre")
        g.gemm(x, "omega_head", "omega_pre")
        g.node("Sigmoid", ["v_pre"], "v")
        g.node("Tanh", ["omega_pre"], "omega")
        return g.node("Concat", ["v", "omega"], "action", axis=1)
    mean = g.gemm(x, "mean" if kind == "squashed" else "head", "mean_pre")
    t = g.node("Tanh", [mean], f"{mean}.tanh")
    scaled = g.node("Mul", [g.const("box.scale", [[0.5, 1.0]]), t], f"{mean}.scaled")
    return g.node("Add", [g.const("box.loc", [[0.5, 0.0]]), scaled], "action")

"""Load torchvision-layout MobileNetV2 weights into :class:`jaxsem.models.MobileNetV2`.

torch is not needed: the input is a flat mapping of numpy arrays keyed like torchvision's
``state_dict()`` (``features.0.0.weight``, ``features.1.conv.0.0.weight``, ...), e.g. loaded
with ``numpy.load`` from an ``.npz`` the user exported. Convolution weights are OIHW (depthwise
``(C, 1, 3, 3)``), transposed here to flax's HWIO; batch-norm ``weight``/``bias`` become
``scale``/``bias`` params and ``running_mean``/``running_var`` the ``batch_stats`` ``mean``/``var``
(``num_batches_tracked`` and the ``classifier.*`` keys are ignored).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import numpy as np

from ._mobilenet import MobileNetV2, block_layout


def _conv(sd, key, prefix_used):
    w = np.asarray(sd[key + ".weight"])
    prefix_used.add(key + ".weight")
    if w.ndim != 4:
        raise ValueError(f"{key}.weight: expected a 4-D OIHW convolution weight, got shape {w.shape}")
    return {"kernel": np.transpose(w, (2, 3, 1, 0))}


def _bn(sd, key, used):
    for s in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked"):
        used.add(f"{key}.{s}")
    params = {"scale": np.asarray(sd[key + ".weight"]), "bias": np.asarray(sd[key + ".bias"])}
    stats = {"mean": np.asarray(sd[key + ".running_mean"]), "var": np.asarray(sd[key + ".running_var"])}
    return params, stats


def convert_torchvision_mobilenet_v2(
    state_dict: Mapping[str, np.ndarray], width_multiplier: float = 1.0, dtype=np.float32
):
    """torchvision ``mobilenet_v2`` state dict -> flax ``{"params": ..., "batch_stats": ...}``.

    Args:
      state_dict: mapping from torchvision keys to arrays (numpy or anything ``np.asarray`` takes).
      width_multiplier: the ``width_mult`` the weights were trained with.
      dtype: dtype of the returned arrays.

    Returns:
      variables for ``MobileNetV2(width_multiplier)``; use them directly or graft them under
      ``params["local_backbone"]`` / ``params["global_backbone"]`` of a VoluMon model.

    Raises:
      ValueError: a key is missing or a shape does not match the architecture (naming the key).
    """
    layout = block_layout(width_multiplier)
    used: set[str] = set()
    params: dict = {}
    stats: dict = {}

    def conv_bn(torch_prefix):
        c = _conv(state_dict, f"{torch_prefix}.0", used)
        p, s = _bn(state_dict, f"{torch_prefix}.1", used)
        return {"conv": c, "bn": p}, {"bn": s}

    try:
        params["features_0"], stats["features_0"] = conv_bn("features.0")
        for i, (_, _, _, t) in enumerate(layout):
            name, pre = f"features_{i + 1}", f"features.{i + 1}.conv"
            bp, bs = {}, {}
            j = 0
            if t != 1:
                bp["expand"], bs["expand"] = conv_bn(f"{pre}.0")
                j = 1
            bp["depthwise"], bs["depthwise"] = conv_bn(f"{pre}.{j}")
            proj_c = _conv(state_dict, f"{pre}.{j + 1}", used)
            proj_p, proj_s = _bn(state_dict, f"{pre}.{j + 2}", used)
            bp["project"] = {"conv": proj_c, "bn": proj_p}
            bs["project"] = {"bn": proj_s}
            params[name], stats[name] = bp, bs
        last = f"features_{len(layout) + 1}"
        params[last], stats[last] = conv_bn(f"features.{len(layout) + 1}")
    except KeyError as exc:
        raise ValueError(
            f"state_dict: missing key {exc.args[0]!r} for a torchvision MobileNetV2 with width_multiplier="
            f"{width_multiplier}"
        ) from None

    # check shapes against the architecture before anyone runs it
    expected = jax.eval_shape(
        lambda: MobileNetV2(width_multiplier).init(jax.random.PRNGKey(0), np.zeros((1, 32, 32, 3), np.float32))
    )
    out = {"params": params, "batch_stats": stats}
    flat_exp = dict(jax.tree_util.tree_flatten_with_path(expected)[0])
    flat_got = dict(jax.tree_util.tree_flatten_with_path(out)[0])
    for path, leaf in flat_exp.items():
        if path not in flat_got:
            raise ValueError(f"state_dict: no weight for {jax.tree_util.keystr(path)}")
        if tuple(np.shape(flat_got[path])) != tuple(leaf.shape):
            raise ValueError(
                f"state_dict: weight for {jax.tree_util.keystr(path)} has shape {np.shape(flat_got[path])} "
                f"(after OIHW->HWIO), expected {tuple(leaf.shape)} for width_multiplier={width_multiplier}"
            )
    return jax.tree.map(lambda x: np.asarray(x, dtype), out)


def load_backbone_into_volumon(variables, backbone_variables, branches=("local_backbone", "global_backbone")):
    """Return VoluMon ``variables`` with the given MobileNetV2 variables grafted into its branches."""
    params = dict(variables["params"])
    stats = dict(variables.get("batch_stats", {}))
    for b in branches:
        params[b] = backbone_variables["params"]
        stats[b] = backbone_variables["batch_stats"]
    return {**variables, "params": params, "batch_stats": stats}

"""MobileNetV2 feature extractor in flax linen, laid out like torchvision's ``mobilenet_v2``.

The blocks, channel rounding (``_make_divisible``), symmetric padding, ReLU6, batch-norm epsilon
(1e-5) and momentum (torch 0.1 == flax 0.9) follow torchvision exactly, so that
:func:`jaxsem.models.convert_torchvision_mobilenet_v2` can load its weights and give the same
features. Module names mirror torchvision's ``features.<i>`` indices (``features_<i>``).

Input ``(..., H, W, 3)`` float images (NHWC, any size: the thesis uses 224 x 224, the CPU default
is 64 x 64); output ``(..., last_channel)`` globally average-pooled features (torchvision's
``features`` followed by ``adaptive_avg_pool2d``), or the feature map with ``pool=False``.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax.numpy as jnp

# torchvision's inverted_residual_setting: expansion t, output channels c, repeats n, stride s.
INVERTED_RESIDUAL_SETTING: tuple[tuple[int, int, int, int], ...] = (
    (1, 16, 1, 1),
    (6, 24, 2, 2),
    (6, 32, 3, 2),
    (6, 64, 4, 2),
    (6, 96, 3, 1),
    (6, 160, 3, 2),
    (6, 320, 1, 1),
)

BN_EPSILON = 1e-5
BN_MOMENTUM = 0.9  # flax's decay; torch's momentum=0.1 is the weight of the new batch


def make_divisible(v: float, divisor: int = 8, min_value: int | None = None) -> int:
    """torchvision's ``_make_divisible``: round channels to a multiple of ``divisor`` (>= 90 % of v)."""
    if min_value is None:
        min_value = divisor
    new_v = max(min_value, int(v + divisor / 2) // divisor * divisor)
    if new_v < 0.9 * v:
        new_v += divisor
    return new_v


def block_layout(width_multiplier: float = 1.0) -> list[tuple[int, int, int, int]]:
    """Per inverted-residual block (features 1..17): (in_channels, out_channels, stride, expand)."""
    in_c = make_divisible(32 * width_multiplier)
    layout = []
    for t, c, n, s in INVERTED_RESIDUAL_SETTING:
        out_c = make_divisible(c * width_multiplier)
        for i in range(n):
            layout.append((in_c, out_c, s if i == 0 else 1, t))
            in_c = out_c
    return layout


def last_channel(width_multiplier: float = 1.0) -> int:
    return make_divisible(1280 * max(1.0, width_multiplier))


class ConvBN(nn.Module):
    """Conv (no bias) + BatchNorm + optional ReLU6: torchvision's ``Conv2dNormActivation``."""

    features: int
    kernel: int = 3
    stride: int = 1
    groups: int = 1
    activation: bool = True
    dtype: jnp.dtype | None = None

    @nn.compact
    def __call__(self, x, train: bool):
        p = (self.kernel - 1) // 2
        x = nn.Conv(
            self.features,
            (self.kernel, self.kernel),
            strides=(self.stride, self.stride),
            padding=((p, p), (p, p)),  # symmetric, as torch; flax 'SAME' pads stride-2 asymmetrically
            feature_group_count=self.groups,
            use_bias=False,
            dtype=self.dtype,
            name="conv",
        )(x)
        x = nn.BatchNorm(
            use_running_average=not train,
            momentum=BN_MOMENTUM,
            epsilon=BN_EPSILON,
            dtype=self.dtype,
            name="bn",
        )(x)
        return nn.relu6(x) if self.activation else x


class InvertedResidual(nn.Module):
    """Expand (1x1) -> depthwise 3x3 -> linear projection (1x1), residual when shapes allow."""

    in_channels: int
    out_channels: int
    stride: int
    expand_ratio: int
    dtype: jnp.dtype | None = None

    @nn.compact
    def __call__(self, x, train: bool):
        hidden = int(round(self.in_channels * self.expand_ratio))
        y = x
        if self.expand_ratio != 1:
            y = ConvBN(hidden, kernel=1, dtype=self.dtype, name="expand")(y, train)
        y = ConvBN(hidden, kernel=3, stride=self.stride, groups=hidden, dtype=self.dtype, name="depthwise")(y, train)
        y = ConvBN(self.out_channels, kernel=1, activation=False, dtype=self.dtype, name="project")(y, train)
        if self.stride == 1 and self.in_channels == self.out_channels:
            y = x + y
        return y


class MobileNetV2(nn.Module):
    """MobileNetV2 features (torchvision layout) with global average pooling.

    Attributes:
      width_multiplier: channel multiplier (torchvision ``width_mult``); 1.0 in the thesis.
      pool: average the final feature map over space (default) or return it (..., h, w, C).
      dtype: computation dtype (params stay float32).
    """

    width_multiplier: float = 1.0
    pool: bool = True
    dtype: jnp.dtype | None = None

    @nn.compact
    def __call__(self, x, train: bool = False):
        x = ConvBN(make_divisible(32 * self.width_multiplier), kernel=3, stride=2, dtype=self.dtype, name="features_0")(
            x, train
        )
        for i, (cin, cout, s, t) in enumerate(block_layout(self.width_multiplier)):
            x = InvertedResidual(cin, cout, s, t, dtype=self.dtype, name=f"features_{i + 1}")(x, train)
        n = len(block_layout(self.width_multiplier)) + 1
        x = ConvBN(last_channel(self.width_multiplier), kernel=1, dtype=self.dtype, name=f"features_{n}")(x, train)
        if self.pool:
            x = jnp.mean(x, axis=(-3, -2))
        return x


def feature_dim(width_multiplier: float) -> int:
    """Size of the pooled feature vector of :class:`MobileNetV2`."""
    return last_channel(width_multiplier)


__all__: Sequence[str] = ["MobileNetV2", "make_divisible", "block_layout", "feature_dim"]

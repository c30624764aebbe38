"""Every tuned number of the render path in one frozen ``RenderOptions``, made of the stages' own options.

`render` and `eval` take it (``RenderConfig.options``, ``EvalConfig.options``) and record it in render_config.json,
the eval JSON and both HTML pages, so an output says which rules made it; a render resumed under other options is
refused. Benches and tests vary it with ``dataclasses.replace``. Each stage defines its own options next to the code
that reads them; this module only gathers them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from insertnerf_cli.model.guide import GuideOptions
from insertnerf_cli.rendering.image_renderer import Shortcuts
from insertnerf_cli.rendering.prior_blend import BlendOptions
from insertnerf_cli.sfm.depth_prior import PriorOptions
from insertnerf_cli.sfm.occlusion_maps import OcclusionOptions


@dataclass(frozen=True)
class ColourOptions:
    """Where the references' colours that a frame blends are looked up.

    Attributes:
        scale: in the photos at up to this many times the frame's size (never above their own): a bilinear lookup
            at the frame's size blurs each colour over two frame pixels. 1: at the frame's size, in the images the
            encoder sees.
    """

    scale: float = 2.0

    def __post_init__(self) -> None:
        if self.scale < 1.0:
            raise ValueError(f"the colour lookup scale must be at least 1, got {self.scale}")


@dataclass(frozen=True)
class RenderOptions:
    """The render path's rules, one dataclass per stage (docs/method.md describes each stage).

    Attributes:
        prior: which SfM points make a frame's depth prior and how they are drawn (sfm/depth_prior.py).
        guide: how the fine samples follow the prior (model/guide.py).
        occlusion: the references' occlusion maps (sfm/occlusion_maps.py, model/occlusion.py).
        blend: the blend at the prior (rendering/prior_blend.py).
        colours: the colour lookups (rendering/view_renderer.py).
        shortcuts: the work a frame skips (rendering/image_renderer.py); ``--exact`` replaces it with EXACT.
    """

    prior: PriorOptions = field(default_factory=PriorOptions)
    guide: GuideOptions = field(default_factory=GuideOptions)
    occlusion: OcclusionOptions = field(default_factory=OcclusionOptions)
    blend: BlendOptions = field(default_factory=BlendOptions)
    colours: ColourOptions = field(default_factory=ColourOptions)
    shortcuts: Shortcuts = field(default_factory=Shortcuts)

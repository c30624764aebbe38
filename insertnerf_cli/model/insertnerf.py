"""InsertNeRF: a vanilla NeRF made generalizable by HyperNet modules fed with multi-view features."""
from __future__ import annotations

import torch
from torch import Tensor, nn

from insertnerf_cli.cameras.rays import Rays
from insertnerf_cli.config import ModelConfig
from insertnerf_cli.model.aggregate import ScaleAggregator, angular_prior, reweigh
from insertnerf_cli.model.compositing import Composite, composite, composite_weights
from insertnerf_cli.model.consistency import colour_variance, sharpen
from insertnerf_cli.model.encoder import UNetEncoder, pad_to_stride
from insertnerf_cli.model.guide import guide_weights
from insertnerf_cli.model.inverted_sphere import Sphere, background_samples, inverted_sphere
from insertnerf_cli.model.losses import compute_losses
from insertnerf_cli.model.nerf import NeRFHead
from insertnerf_cli.model.projection import project_samples, projection_matrices, ray_angle
from insertnerf_cli.model.sampling import RaySamples, importance_samples, stratified_samples
from insertnerf_cli.model.types import EncodedViews, LossTerms, RenderOutput, SampleFeatures, SourceViews
from insertnerf_cli.scenes.normalize import OBJECT_RADIUS

# The infinity sample's depth in units of the ray's far bound (InsertNeRF.backdrop).
_INFINITY_FACTOR = 1e4


class InsertNeRF(nn.Module):
    """The generator: reference views + query rays -> colour, depth and opacity of both passes."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        cfg = config
        self.encoder = UNetEncoder(cfg.encoder_widths, cfg.feature_dims, cfg.backbone_decoder_width)
        # The reference colour joins the finest scale only: it is a full-resolution signal.
        in_dims = [*cfg.feature_dims[:-1], cfg.feature_dims[-1] + 3]
        self.aggregators = nn.ModuleList(
            ScaleAggregator(in_dim, dim // 2, cfg.aggregate_hidden, cfg.static_sharpness_init, cfg.visibility_cue)
            for in_dim, dim in zip(in_dims, cfg.feature_dims))
        cond_dims = [agg.out_dim for agg in self.aggregators]
        self.coarse_head = NeRFHead(cfg, cond_dims, cfg.samples_coarse)
        # Shared by default: on a CPU budget one head gets the gradients of both passes (see docs/model.md).
        self.fine_head = NeRFHead(cfg, cond_dims, cfg.samples_fine) if cfg.separate_fine_head else self.coarse_head
        # NeRF++: the same conditioned field over the background's inverted-sphere coordinates.
        self.background_head = NeRFHead(cfg, cond_dims, cfg.samples_background, position_dims=4) \
            if cfg.backbone == "nerfpp" else None
        self.register_buffer("background", torch.tensor(cfg.background, dtype=torch.float32), persistent=False)

    def compile_aggregation(self) -> None:
        """Run the per-scale aggregators through torch.compile, in place (the state dict is unchanged).

        The aggregation is the memory-bound part of a step: element-wise passes over [V, C, P] per-view tensors,
        which the compiler fuses (bench/train_throughput.py --compile; docs/benchmarks.md). Dynamic
        shapes: one compile serves every ray count (coarse and fine pass, validation). Compiling the whole step
        instead was slower on the CPU.
        """
        for aggregator in self.aggregators:
            aggregator.compile(dynamic=True)

    def encode(self, views: SourceViews) -> EncodedViews:
        """U-Net features of the reference views; in training mode also the backbone reconstruction."""
        param = self.background
        images = pad_to_stride(views.images.to(param).permute(0, 3, 1, 2))  # [V, 3, Hp, Wp]
        features = self.encoder(images)
        cameras = views.cameras.to(device=param.device, dtype=param.dtype)
        height, width = cameras.height, cameras.width
        recon = None
        if self.training and torch.is_grad_enabled():
            recon = self.encoder.reconstruct(features[-1])[..., :height, :width]  # [V, 3, H, W]
        return EncodedViews(features=features, images=images, projection=projection_matrices(cameras),
                            centers=cameras.centers, height=height, width=width, reconstruction=recon)

    def forward(self, encoded: EncodedViews, rays: Rays, train: bool, guide: Tensor | None = None) -> RenderOutput:
        """Render R rays: stratified coarse pass, then an importance-sampled fine pass; with ``guide`` [R] (a
        depth per ray, NaN where none) the fine samples follow the coarse weights guided to it as render's SfM
        prior guides them (model.guide.guide_weights)."""
        cfg = self.config
        rays = rays.to(device=self.background.device, dtype=self.background.dtype)
        backdrop = self.backdrop(encoded, rays, train)  # [R, 3] what the ray sees past the foreground
        coarse_samples = stratified_samples(rays, cfg.samples_coarse, jitter=train,
                                            in_disparity=cfg.sample_in_disparity)
        coarse, dynamic_coarse = self.render_pass(self.coarse_head, encoded, rays, coarse_samples, backdrop,
                                                  cfg.consistency_temperature_coarse)
        weights = coarse.weights if guide is None else guide_weights(coarse.weights.detach(), coarse_samples.t, guide)
        fine_samples = importance_samples(coarse_samples, weights, cfg.samples_fine, jitter=train,
                                          near=rays.near, far=rays.far)
        fine, dynamic_fine = self.render_pass(self.fine_head, encoded, rays, fine_samples, backdrop,
                                              cfg.consistency_temperature_fine)
        return RenderOutput(coarse=coarse, fine=fine, dynamic_coarse=dynamic_coarse, dynamic_fine=dynamic_fine,
                            coarse_samples=coarse_samples, fine_samples=fine_samples)

    def backdrop(self, encoded: EncodedViews, rays: Rays, train: bool = False) -> Tensor:
        """[R, 3] the colour behind everything the foreground samples hold: with the NeRF++ backbone the background
        field composited over what lies past it; past that, with ``infinity_sample`` a sample at infinity (the
        ray's direction, which every reference view sees at its vanishing point, aggregated like any sample);
        else, and for rays no view sees there, the fixed background colour."""
        fixed = self.background.to(rays.directions).expand(len(rays), 3)
        if self.config.infinity_sample:
            # Far enough that the projection is the vanishing point to well under a pixel, near enough for float32.
            t = (rays.far * _INFINITY_FACTOR)[:, None]  # [R, 1]
            seen = self.observe(encoded, rays, RaySamples(t, torch.cat([t, t], dim=-1)))
            coverage = seen.dynamic.sum(dim=0)[0]  # [R]: 1 where some view sees the direction, else 0
            fixed = seen.reference_colour()[:, 0] + (1.0 - coverage)[:, None] * fixed
        if self.background_head is None:
            return fixed
        return self.background_field(encoded, rays, fixed, train).rgb

    def sphere(self, encoded: EncodedViews) -> Sphere:
        """The foreground's sphere (NeRF++): about the world's origin, where scene normalisation puts an object
        capture's subject and a forward capture's cameras; ``foreground_margin`` times as wide as the farthest
        reference camera, and at least as wide as normalisation's camera orbit."""
        centres = encoded.centers
        reach = centres.norm(dim=-1).max().clamp_min(OBJECT_RADIUS)
        return Sphere(centres.new_zeros(3), self.config.foreground_margin * reach)

    def background_field(self, encoded: EncodedViews, rays: Rays, behind: Tensor, train: bool) -> Composite:
        """NeRF++'s background: ``samples_background`` samples evenly in inverse distance from the sphere out to
        (nearly) infinity, seen by the reference views like any sample, the conditioned field reading their
        inverted-sphere coordinates, composited over ``behind`` [R, 3] with densities integrated over inverse
        distance (NeRF++'s measure: a far bin counts as much as a near one)."""
        sphere = self.sphere(encoded)
        samples = background_samples(rays, sphere, self.config.samples_background, jitter=train)
        t_edges = torch.cat([samples.t[:, :1], samples.t], dim=-1)  # projection reads only t
        seen = self.observe(encoded, rays, RaySamples(samples.t, t_edges))
        field = self.background_head(inverted_sphere(seen.points, sphere), rays.directions, seen.conds)
        colour = field.colour
        if self.config.blend_reference_colour:
            colour = field.blend * colour + (1.0 - field.blend) * seen.reference_colour()
        weights = composite_weights(field.density, -samples.edges, torch.ones_like(rays.near))
        return composite(weights, colour, samples.t, behind)

    def inside(self, encoded: EncodedViews, points: Tensor) -> Tensor | None:
        """[R, S] 1 for the samples ``points`` [R, S, 3] inside the foreground's sphere, 0 outside (the background
        field's), or None with the NeRF backbone (one field everywhere)."""
        if self.background_head is None:
            return None
        sphere = self.sphere(encoded)
        return ((points - sphere.centre).norm(dim=-1) <= sphere.radius).to(points)

    def render(self, encoded: EncodedViews, rays: Rays) -> Composite:
        """Inference: the fine composite of R rays, the same as ``forward(..., train=False).fine``."""
        coarse_samples, weights = self.coarse_weights(encoded, rays)
        return self.render_fine(encoded, rays, coarse_samples, weights)

    def coarse_weights(self, encoded: EncodedViews, rays: Rays) -> tuple[RaySamples, Tensor]:
        """Inference: the coarse samples of R rays and their compositing weights [R, S_c].

        The coarse pass only places the fine samples, so it stops at the densities: no appearance branch and
        none of the reference-colour composites that training supervises.
        """
        cfg = self.config
        rays = rays.to(device=self.background.device, dtype=self.background.dtype)
        samples = stratified_samples(rays, cfg.samples_coarse, jitter=False, in_disparity=cfg.sample_in_disparity)
        coarse = self.observe(encoded, rays, samples, colour=False,
                              variance=bool(cfg.consistency_temperature_coarse))
        _, density = self.coarse_head.geometry(coarse.points, coarse.conds)
        if (inside := self.inside(encoded, coarse.points)) is not None:
            density = density * inside
        weights = composite_weights(density, samples.edges, rays.directions.norm(dim=-1))
        if cfg.consistency_temperature_coarse:
            weights = sharpen(weights, coarse.colour_variance, cfg.consistency_temperature_coarse)
        return samples, weights

    def render_fine(self, encoded: EncodedViews, rays: Rays, coarse_samples: RaySamples,
                    weights: Tensor, backdrop: Tensor | None = None) -> Composite:
        """Inference: the fine composite of R rays whose fine samples follow ``weights`` [R, S_c] on
        ``coarse_samples`` (their own coarse pass, or one borrowed from neighbouring pixels: render.py), over
        ``backdrop`` [R, 3] (default: self.backdrop of the rays)."""
        cfg = self.config
        rays = rays.to(device=self.background.device, dtype=self.background.dtype)
        fine_samples = importance_samples(coarse_samples, weights, cfg.samples_fine, jitter=False,
                                          near=rays.near, far=rays.far)
        fine = self.observe(encoded, rays, fine_samples, variance=bool(cfg.consistency_temperature_fine))
        behind = self.backdrop(encoded, rays) if backdrop is None else backdrop
        return self.shade(self.fine_head, fine, rays, fine_samples, fine.reference_colour(), behind,
                          cfg.consistency_temperature_fine, self.inside(encoded, fine.points))

    def render_pass(self, head: NeRFHead, encoded: EncodedViews, rays: Rays, samples: RaySamples,
                    backdrop: Tensor, temperature: float = 0.0) -> tuple[Composite, Tensor]:
        """sample -> project -> aggregate -> hypernet + nerf -> composite, for one set of samples
        (``temperature``: the pass's photo-consistency, 0 = none).

        Returns the composite and the dynamic-weight colour [R, 3] composited with the detached weights.
        """
        seen = self.observe(encoded, rays, samples, variance=bool(temperature))
        reference = seen.reference_colour()  # [R, S, 3]
        main = self.shade(head, seen, rays, samples, reference, backdrop, temperature,
                          self.inside(encoded, seen.points))
        return main, composite(main.weights.detach(), reference, samples.t, backdrop).rgb

    def observe(self, encoded: EncodedViews, rays: Rays, samples: RaySamples, colour: bool = True,
                variance: bool = False) -> SampleFeatures:
        """Project the samples into every reference view and aggregate what the views see, per scale.

        ``colour=False``: the caller uses no reference colour (the inference coarse pass), so the colour prior,
        which changes nothing else, is skipped. ``variance``: also the photo-consistency cost the caller's
        sharpening needs (SampleFeatures.colour_variance).
        """
        points = samples.points(rays)  # [R, S, 3]
        rays_n, samples_n = points.shape[:2]
        seen = project_samples(encoded, points, rays.directions, finer=colour)
        if self.config.sample_views:
            seen = seen.nearest_in_angle(self.config.sample_views)
        seen = seen.unoccluded()  # the views that see a nearer surface in front of a sample drop out
        prior_views = self.config.colour_prior_views if colour else 0
        # One angle per view and sample serves the colour prior and the cue's prior (the asin is a third of each).
        angle = ray_angle(seen.ray_diff) if variance or prior_views else None  # [V, 1, P]
        cost = None
        if variance:
            weights = angular_prior(seen.ray_diff, seen.mask, self.config.consistency_views, angle)
            cost = colour_variance(seen.colours, seen.mask, weights, samples_n)  # [R, S]
        inputs = [*seen.features[:-1], torch.cat([seen.features[-1], seen.colours], dim=1)]  # [V, C_l, P]
        descriptors, dynamics = zip(*(agg(f, seen.mask, seen.ray_diff) for agg, f in zip(self.aggregators, inputs)))
        dynamic = torch.stack(dynamics).mean(dim=0)  # [V, 1, P]
        if prior_views:
            dynamic = reweigh(dynamic, angular_prior(seen.ray_diff, seen.mask, prior_views, angle))
        return SampleFeatures(points=points, conds=tuple(d.reshape(rays_n, samples_n, -1) for d in descriptors),
                              dynamic=dynamic, colours=seen.blend_colours, colour_variance=cost)

    def shade(self, head: NeRFHead, seen: SampleFeatures, rays: Rays, samples: RaySamples,
              reference: Tensor, backdrop: Tensor, temperature: float = 0.0, inside: Tensor | None = None) -> Composite:
        """The conditioned field at the samples, blended with the reference colour [R, S, 3], composited over
        ``backdrop`` [R, 3]; with ``temperature`` > 0 the weights sharpened toward photo-consistent samples; with
        ``inside`` [R, S] the density kept only where it is 1 (NeRF++'s foreground)."""
        field = head(seen.points, rays.directions, seen.conds)
        colour = field.colour
        if self.config.blend_reference_colour:
            colour = field.blend * colour + (1.0 - field.blend) * reference  # [R, S, 3]
        density = field.density if inside is None else field.density * inside
        weights = composite_weights(density, samples.edges, rays.directions.norm(dim=-1))
        if temperature:
            weights = sharpen(weights, seen.colour_variance, temperature)
        return composite(weights, colour, samples.t, backdrop)

    def losses(self, output: RenderOutput, target_rgb: Tensor, encoded: EncodedViews, rays: Rays | None = None,
               target_depth: Tensor | None = None) -> LossTerms:
        """Colour MSE on both passes + weighted backbone, dynamic-weight and geometry losses (see losses.py)."""
        return compute_losses(self.config, output, target_rgb, encoded, rays, target_depth)

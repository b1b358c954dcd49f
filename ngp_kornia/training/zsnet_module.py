"""Training ZSNet with Lightning: candidates are sampled from each batch's segments exactly as the parser samples
them at inference, labelled against the true zenith (Eq. 8) and scored; loss = cross entropy + localisation."""

from __future__ import annotations

import torch
from torch import Tensor

from ngp_kornia.geometry import (
    homogeneous_to_pseudo_camera,
    pseudo_focal,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
)
from ngp_kornia.metrics import zenith_error_deg
from ngp_kornia.nets.zsnet import ZSNet, zenith_estimate, zenith_weights_from_scores
from ngp_kornia.pipeline.candidates import sample_zenith_candidates
from ngp_kornia.training.base import NetworkModule
from ngp_kornia.training.losses import zenith_classification_loss, zenith_labels, zenith_localisation_loss
from ngp_kornia.training.scene_data import SceneBatch

__all__ = ["ZSNetModule"]


class ZSNetModule(NetworkModule):
    """Lightning wrapper of a :class:`ZSNet`.

    Args:
        net: the network (passed in; not saved as a hyperparameter).
        lr: Adam learning rate (the paper: 1e-3).
        lr_step: epochs between halvings of the learning rate (the paper: 5).
        localisation_weight: weight of the structure-tensor loss (Eq. 10-11).
        num_lines: |L_z|.
        num_candidates: |Z|.
        zenith_threshold: delta_c of Eq. 12, for the logged zenith estimate.
    """

    def __init__(
        self,
        net: ZSNet,
        lr: float = 1e-3,
        lr_step: int = 5,
        localisation_weight: float = 1.0,
        num_lines: int = 256,
        num_candidates: int = 256,
        zenith_threshold: float = 0.5,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net

    def forward(self, lines: Tensor, line_mask: Tensor, zeniths: Tensor) -> Tensor:
        return self.net(lines, line_mask, zeniths)

    def _inputs(self, batch: SceneBatch, generator: torch.Generator | None = None) -> tuple[Tensor, ...]:
        height, width = (int(v) for v in batch.image_size[0])
        lines = segments_to_lines(to_pseudo_camera(batch.segments, height, width))
        lengths = segment_lengths(batch.segments) * batch.mask.to(lines)
        lz, lz_ok, z, z_ok = sample_zenith_candidates(
            lines, lengths, batch.mask, self.hparams.num_lines, self.hparams.num_candidates, generator=generator
        )
        z_gt = homogeneous_to_pseudo_camera(batch.zenith, height, width)
        focal = batch.K[:, 0, 0] / pseudo_focal(height, width)
        return lz, lz_ok, z, z_ok, z_gt, focal

    def _step(self, batch: SceneBatch, stage: str, batch_idx: int) -> Tensor:
        # validation and test sample the same candidates every epoch, so their figures are comparable
        generator = None if stage == "train" else torch.Generator().manual_seed(batch_idx)
        lz, lz_ok, z, z_ok, z_gt, focal = self._inputs(batch, generator)
        logits = self.net(lz, lz_ok, z)
        labels, labelled = zenith_labels(z, z_gt, z_ok)
        scores = torch.sigmoid(logits)
        cls = zenith_classification_loss(logits, labels, labelled)
        loc = zenith_localisation_loss(scores, z, z_ok, z_gt)
        loss = cls + self.hparams.localisation_weight * loc
        # validation and test figures are epoch means: under DDP each process sees a share of the set, so average
        # them over the processes (the checkpoint callback monitors val/zenith_error); a no-op in one process
        opts = {"batch_size": len(batch), "sync_dist": stage != "train"}
        self.log(f"{stage}/loss", loss, prog_bar=True, **opts)
        self.log(f"{stage}/loss_cls", cls, **opts)
        self.log(f"{stage}/loss_loc", loc, **opts)
        if stage != "train":
            est = zenith_estimate(z, zenith_weights_from_scores(scores, z_ok, self.hparams.zenith_threshold))
            uniform = zenith_estimate(z, z_ok.to(z))
            self.log(f"{stage}/zenith_error", zenith_error_deg(est, z_gt, focal).mean(), **opts)
            self.log(f"{stage}/zenith_error_uniform", zenith_error_deg(uniform, z_gt, focal).mean(), **opts)
        return loss

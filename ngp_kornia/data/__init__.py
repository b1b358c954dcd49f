"""Data: the York Urban DB and NYU-VP readers, CSV manifests, image folders, panorama crops and the scene renderer."""

from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.manifest import CSVManifest, ManifestError, ManifestSample
from ngp_kornia.data.nyu import NYU_K, NYUVP, NYUVPSample, nyu_up
from ngp_kornia.data.panorama import crop_ground_truth, perspective_crops, sample_crop_params
from ngp_kornia.data.yud import YorkUrbanDB, YUDSample, load_labelled_segments, published_horizon, rotation_from_yud_vps

__all__ = [
    "CSVManifest",
    "ImageFolder",
    "ManifestError",
    "ManifestSample",
    "NYUVP",
    "NYUVPSample",
    "NYU_K",
    "YUDSample",
    "YorkUrbanDB",
    "crop_ground_truth",
    "load_labelled_segments",
    "nyu_up",
    "perspective_crops",
    "published_horizon",
    "rotation_from_yud_vps",
    "sample_crop_params",
]

"""Batched, differentiable torch geometry of the Neural Geometric Parser. Knows nothing of the networks."""

from ngp_kornia.geometry.camera import *  # noqa: F403
from ngp_kornia.geometry.camera import __all__ as _camera_all
from ngp_kornia.geometry.frames import *  # noqa: F403
from ngp_kornia.geometry.frames import __all__ as _frames_all
from ngp_kornia.geometry.lens import *  # noqa: F403
from ngp_kornia.geometry.lens import __all__ as _lens_all
from ngp_kornia.geometry.line_algebra import *  # noqa: F403
from ngp_kornia.geometry.line_algebra import __all__ as _lines_all
from ngp_kornia.geometry.line_maps import *  # noqa: F403
from ngp_kornia.geometry.line_maps import __all__ as _raster_all
from ngp_kornia.geometry.pinhole import *  # noqa: F403
from ngp_kornia.geometry.pinhole import __all__ as _pinhole_all
from ngp_kornia.geometry.rectify import *  # noqa: F403
from ngp_kornia.geometry.rectify import __all__ as _rectify_all
from ngp_kornia.geometry.vp import *  # noqa: F403
from ngp_kornia.geometry.vp import __all__ as _vp_all

__all__ = [*_camera_all, *_frames_all, *_lens_all, *_lines_all, *_raster_all, *_pinhole_all, *_rectify_all, *_vp_all]

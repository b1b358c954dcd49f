"""The ``ngp`` command line: ``ngp calibrate IMAGE...``, ``ngp predict FOLDER``, ``ngp rectify IMAGE``, ``ngp demo``,
``ngp render OUTDIR``."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from ngp_kornia.cli_camera import add_camera_arguments, camera_arguments, images_after_the_point, load_truth
from ngp_kornia.cli_colmap import add_colmap_argument
from ngp_kornia.cli_files import check_output, check_overlays, overlay_path, write_image, write_overlay
from ngp_kornia.cli_options import (
    add_setting_options,
    closest_option,
    config_from_args,
    settings_from_args,
    short_usage,
    subcommand,
)
from ngp_kornia.cli_output import Table, orientation_doubt, print_result, warn_if_turned
from ngp_kornia.cli_predict import add_predict_arguments, check_predict, predict_command
from ngp_kornia.cli_render import add_render_command, render_command
from ngp_kornia.errors import ConfigError, NGPError, NGPWarning

if TYPE_CHECKING:
    import numpy as np

    from ngp_kornia.pipeline import ParserConfig

# Nothing heavy is imported here: parse() answers --help, --version and wrong arguments before torch, OpenCV or
# Lightning is loaded (seconds); each command imports what it needs when it runs.
__all__ = ["main", "parse", "run"]

#: what the commands report as one line ``ngp: error: <message>`` instead of a traceback (with kornia's check
#: errors, see _user_errors)
USER_ERRORS = (NGPError, ValueError, TypeError, OSError)
FORCE_HELP = "overwrite an output file (never an input)"
WEIGHTS_HELP = "default, none, zsnet, fsnet, full, or a .pt file"
#: the last lines of the help of a command with pipeline settings
SETTINGS_EPILOG = "Every pipeline setting (e.g. --segments.working_size 640, --horizon.refine false): --help-all."


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default where it has one worth showing (not None, False or already in the help), and the
    options' help from the 26th column, so that a command's everyday options fit a screen."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=26)

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None or action.default is False:
            return action.help or ""
        return super()._get_help_string(action)

    def _format_args(self, action: argparse.Action, default_metavar: str) -> str:
        shown = getattr(action, "shown_args", None)  # "CX CY | estimate" rather than argparse's "X [X ...]"
        return shown if shown is not None else super()._format_args(action, default_metavar)


class _VersionAction(argparse.Action):
    """``--version``: prints the package version."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from ngp_kornia import __version__

        print(f"{parser.prog} {__version__}")
        parser.exit()


def _user_errors() -> tuple[type[BaseException], ...]:
    """USER_ERRORS, and kornia's check errors once kornia is loaded (none can be raised before)."""
    kornia = sys.modules.get("kornia.core.exceptions")
    return USER_ERRORS if kornia is None else (*USER_ERRORS, kornia.BaseError)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ngp", description="Single-image camera calibration for man-made scenes.", formatter_class=_HelpFormatter
    )
    p.add_argument("--version", action=_VersionAction, help="print the version and exit")
    sub = p.add_subparsers(dest="command", required=True)
    cal = sub.add_parser("calibrate", help="calibrate photos: a table on a terminal, JSON lines otherwise",
                         description="Focal length, field of view, pitch and roll of photos of man-made scenes: a "
                         "table on a terminal, JSON lines with --json or in a pipe.", epilog=SETTINGS_EPILOG)
    cal.add_argument("images", nargs="*", help="image files (at least one)")
    cal.add_argument("--weights", metavar="NAME", default="default", help=WEIGHTS_HELP)
    cal.add_argument("--seed", metavar="N", type=int, default=0, help="seed of the random sampling")
    cal.add_argument("--json", action="store_true", help="one JSON object per image, also on a terminal")
    cal.add_argument("--overlay", metavar="PNG", help="draw the answer over the photo (a folder for several)")
    cal.add_argument("--truth", metavar="FILE", help="also draw the true horizon: a CSV or an ngp render folder")
    cal.add_argument("--force", action="store_true", help=FORCE_HELP)
    _add_prior_arguments(cal, "one camera took them all: one focal length")
    pred = sub.add_parser("predict", help="calibrate every image of a folder or a list into a JSON Lines file",
                          epilog=SETTINGS_EPILOG)
    add_predict_arguments(pred)
    add_colmap_argument(pred)
    _add_prior_arguments(pred, "one camera per folder: one focal length each")
    _add_rectify(sub)
    demo = sub.add_parser("demo", help="calibrate a built-in rendered example and print the estimate and the truth")
    demo.add_argument("--overlay", help="write the overlay PNG here")
    demo.add_argument("--seed", type=int, default=2, help="which built-in scene to render")
    add_render_command(sub)
    for command in sub.choices.values():  # defaults in every --help
        command.formatter_class = _HelpFormatter
        command.usage = short_usage(command)
    return p


def _add_rectify(sub) -> None:
    rect = sub.add_parser("rectify", help="calibrate a photo and write it rectified (level, upright or frontal)",
                          epilog=SETTINGS_EPILOG)
    rect.add_argument("image", help="image file")
    rect.add_argument(
        "--mode",
        choices=("level", "upright", "frontal"),
        default="upright",
        help="level: no roll; upright: no roll nor pitch; frontal: face a facade",
    )
    rect.add_argument("--axis", choices=("x", "z"), default="z", help="--mode frontal: the scene axis to face")
    rect.add_argument("-o", "--output", metavar="PNG", required=True, help="the rectified image to write")
    rect.add_argument(
        "--crop",
        choices=("keep", "valid"),
        help="keep every pixel, or crop to the valid centre (default: keep; valid for frontal)",
    )
    rect.add_argument("--weights", metavar="NAME", default="default", help=WEIGHTS_HELP)
    rect.add_argument("--seed", metavar="N", type=int, default=0, help="seed of the random sampling")
    rect.add_argument("--force", action="store_true", help=FORCE_HELP)
    rect.add_argument("--force-invalid", action="store_true", help="write it even where no camera was found")
    rect.add_argument("--allow-turned", action="store_true",
                      help="rectify it even where the orientation check reads it as turned or doubts it is upright "
                      "(--upright.doubt)")  # fmt: skip
    _add_prior_arguments(rect)


def _add_prior_arguments(command: argparse.ArgumentParser, same_camera: str | None = None) -> None:
    """What is known of the camera (``--focal``, ..., ``--same-camera`` with its help where the command takes it)
    and the pipeline settings (listed by ``--help-all``)."""
    group = command.add_argument_group("what you know of the camera (all optional)")
    focal = group.add_mutually_exclusive_group()  # one prior in three units
    focal.add_argument("--focal", type=float, metavar="PX", help="focal length in pixels of the image")
    focal.add_argument("--focal-35mm", type=float, metavar="MM", help="focal length as a 35 mm equivalent (as EXIF)")
    focal.add_argument("--fov", type=float, metavar="DEG", help="vertical field of view in degrees")
    group.add_argument("--exif", action="store_true", help="each file's EXIF focal length, where it has one")
    add_camera_arguments(group, same_camera)
    add_setting_options(command)


def _config(args: argparse.Namespace) -> ParserConfig:
    """The ParserConfig of the command's ``--stage.field`` options (checked in main()), the defaults for the rest."""
    return config_from_args(args)


def _settings(args: argparse.Namespace) -> dict:
    """The command's ``--stage.field`` options as the mapping ``calibrate(config=...)`` takes: the weight set's own
    settings (those of "default" differ) for the rest."""
    return settings_from_args(args)


def _prior(args: argparse.Namespace, image: str, rgb: np.ndarray) -> dict:
    """calibrate()'s priors for one file: --focal, --fov, else the EXIF focal length with --exif."""
    from ngp_kornia.api import file_priors
    from ngp_kornia.pipeline.priors import Priors

    given = Priors(args.focal, args.fov, focal_35mm=args.focal_35mm)
    priors = file_priors(image, *rgb.shape[:2], given, args.exif)
    return {"focal": priors.focal, "fov_v": priors.fov_v, "focal_35mm": priors.focal_35mm, **camera_arguments(args)}


def _prior_check(args: argparse.Namespace) -> None:
    """The priors of the command line checked once, before any image is read (an error is said once, not per image)."""
    from ngp_kornia.pipeline.priors import Priors

    Priors(args.focal, args.fov, focal_35mm=args.focal_35mm, **camera_arguments(args))


#: images read and calibrated together by ``ngp calibrate`` (one ``calibrate()`` call on a list)
_CHUNK = 8


def _calibrate_loaded(loaded: list, args: argparse.Namespace) -> list:
    """calibrate() on the (image, rgb, orientation) items read, in one call on the list: each file with its own
    priors where they differ (--exif finds different focal lengths)."""
    from ngp_kornia.api import calibrate

    if not loaded:
        return []
    priors = [_prior(args, image, rgb) for image, rgb, _ in loaded]
    options = {"weights": args.weights, "seed": args.seed, "config": _settings(args)}
    if args.same_camera:  # every photo of the command in one call (one chunk, see _calibrate)
        return calibrate([rgb for _, rgb, _ in loaded], **options, priors={**priors[0], "shared_intrinsics": True})
    per_item = {name: [p[name] for p in priors] for name in priors[0]}
    given = {name: values if any(v != values[0] for v in values) else values[0] for name, values in per_item.items()}
    return calibrate([rgb for _, rgb, _ in loaded], **options, priors=given)


def _calibrate(args: argparse.Namespace) -> int:
    from ngp_kornia.api import with_orientation
    from ngp_kornia.io import read_rgb_oriented

    many = len(args.images) > 1
    _prior_check(args)
    if args.overlay:
        check_overlays(args.overlay, args.images, args.force)
    failed, truth = 0, load_truth(args.truth)
    table = Table(args.images) if not args.json and sys.stdout.isatty() else None  # people read, programs parse
    chunk = len(args.images) if args.same_camera else _CHUNK  # one camera: its photos are calibrated together
    for start in range(0, len(args.images), chunk):  # a few images at a time, so results come as they are done
        loaded = []
        for image in args.images[start : start + chunk]:
            try:
                if args.overlay and many:
                    check_output(overlay_path(args.overlay, image, True), args.force, args.images)
                loaded.append((image, *read_rgb_oriented(image)))
            except _user_errors() as err:
                failed += 1
                print(f"ngp: error: {_one_line(err)}", file=sys.stderr, flush=True)
        try:
            results = _calibrate_loaded(loaded, args)
        except _user_errors():  # one image of the chunk failed: find it, keep the others (one camera: all or none)
            if args.same_camera:
                raise
            results = [_calibrate_or_none(image, rgb, args) for image, rgb, _ in loaded]
        for (image, rgb, orientation), result in zip(loaded, results, strict=True):
            if result is None:
                failed += 1
                continue
            result = with_orientation(result, orientation)
            print_result(image, result, table, _config(args).upright.doubt)
            warn_if_turned(image, result, _config(args).upright.doubt)
            try:
                if args.overlay:
                    given = truth.get(Path(image).resolve())
                    write_overlay(overlay_path(args.overlay, image, many), rgb, result, _config(args), given)
            except _user_errors() as err:
                failed += 1
                print(f"ngp: error: {_one_line(err)}", file=sys.stderr, flush=True)
    return 1 if failed else 0


def _calibrate_or_none(image: str, rgb: np.ndarray, args: argparse.Namespace):
    """One image alone; None (and a one-line error) when it cannot be calibrated."""
    from ngp_kornia.api import calibrate

    try:
        options = {"weights": args.weights, "seed": args.seed, "config": _settings(args)}
        return calibrate(rgb, **options, priors=_prior(args, image, rgb))
    except _user_errors() as err:
        print(f"ngp: error: {image}: {_one_line(err)}", file=sys.stderr, flush=True)
        return None


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _predict(args: argparse.Namespace) -> int:
    from ngp_kornia.pipeline.priors import Priors

    priors = Priors(args.focal, args.fov, focal_35mm=args.focal_35mm, **camera_arguments(args))
    return predict_command(args, _settings(args), priors, _user_errors())


def _rectify(args: argparse.Namespace) -> int:
    import torch

    from ngp_kornia.api import calibrate
    from ngp_kornia.geometry.rectify import frontal_homography, level_homography, rectify, upright_homography
    from ngp_kornia.io import read_image_file

    path = Path(args.output)
    try:
        _prior_check(args)
        check_output(path, args.force, [args.image])
        rgb = read_image_file(args.image)
        result = calibrate(rgb, weights=args.weights, seed=args.seed, config=_settings(args),
                           priors=_prior(args, args.image, rgb))
        if not bool(result.valid) and not args.force_invalid:
            print(f"ngp: error: {args.image}: no camera found (valid false, confidence 0: too few lines of man-made "
                  "structure), so there is nothing to rectify; add --force-invalid to write it anyway (a level "
                  "camera: the image as it is)", file=sys.stderr, flush=True)
            return 1
        doubted = orientation_doubt(args.image, result, _config(args).upright.doubt)
        if doubted is not None and not args.allow_turned:
            print(f"ngp: error: {doubted}; add --allow-turned to rectify it as read", file=sys.stderr, flush=True)
            return 1
        K, R = result.K[None].double(), result.R[None].double()
        if args.mode == "level":
            homography = level_homography(K, R)
        elif args.mode == "upright":
            homography = upright_homography(K, R)
        else:
            homography = frontal_homography(K, R, axis=0 if args.axis == "x" else 2)
        image = torch.from_numpy(rgb).permute(2, 0, 1)[None].double().div(255.0)
        crop = args.crop or ("valid" if args.mode == "frontal" else "keep")
        camera = result.camera.apply(lambda t: t[None]).to(torch.float64)  # a lens distortion is undone on the way
        warped, _ = rectify(image, homography, crop=crop, camera=camera)  # too oblique for keep: the error names --crop
        out = warped[0].permute(1, 2, 0).mul(255.0).round().clamp(0, 255).to(torch.uint8).numpy()
        write_image(path, out)
    except _user_errors() as err:
        print(f"ngp: error: {_one_line(err)}", file=sys.stderr, flush=True)
        return 1
    print(f"{args.mode} image ({out.shape[1]}x{out.shape[0]}) written to {path}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from ngp_kornia.api import calibrate
    from ngp_kornia.training.synth.render import render_scene

    scene = render_scene(args.seed)
    calibration = calibrate(scene.image)
    result, truth = calibration.to_dict(), scene.to_dict()
    print(f"built-in example: rendered scene (seed {args.seed}), {scene.image.shape[1]}x{scene.image.shape[0]} px")
    print(f"{'':8}{'estimate':>10}{'truth':>10}")
    for key in ("focal", "fov_v", "fov_h", "pitch", "roll"):
        print(f"{key:8}{result[key]:10.2f}{truth[key]:10.2f}")
    if args.overlay:
        check_output(Path(args.overlay), force=True)
        write_overlay(Path(args.overlay), scene.image, calibration)
        print(f"overlay written to {args.overlay}")
    return 0


def _check_weights(parser: argparse.ArgumentParser, command: str, weights: str) -> None:
    """A bad ``--weights`` is a usage error: reported once, before any image is read, with exit status 2."""
    from ngp_kornia.api import check_weights

    try:
        check_weights(weights)
    except _user_errors() as err:
        subcommands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        subcommands.choices[command].error(f"--weights: {err}")


def _unrecognized(command: argparse.ArgumentParser, extras: list[str]) -> None:
    """A usage error for words the command does not know: its usage, and for a mistyped option the closest one
    (``--focla``: ``did you mean --focal?``). Exits with status 2."""
    for word in extras:
        if word.startswith("-"):
            close = closest_option(command, word)
            hint = f"did you mean {close}?" if close else f"see {command.prog} --help"
            command.error(f"unrecognized option {word}: {hint}")
    command.error(f"unrecognized arguments: {' '.join(extras)}")


def parse(argv: list[str] | None = None) -> argparse.Namespace | int:
    """The command line, checked without importing torch, OpenCV or Lightning.

    ``--help``, ``--version`` and usage errors end here as argparse ends them (SystemExit). An option out of range,
    a command whose extra is not installed, a folder without images or input images that are all missing is one
    ``ngp: error:`` line, and its exit status is returned.

    Returns:
        the arguments for :func:`run`, or the exit status.
    """
    parser = _parser()
    args, extras = parser.parse_known_args(argv)
    if extras:
        _unrecognized(subcommand(parser, args.command), extras)
    if args.command == "calibrate":
        images_after_the_point(args, subcommand(parser, "calibrate"))
    if hasattr(args, "setting:segments.working_size"):
        try:
            _config(args)
        except ConfigError as err:  # it names the setting, e.g. SegmentSettings.working_size
            parser.error(str(err))
    if args.command == "predict" and (code := check_predict(args)) is not None:
        return code
    images = {"calibrate": getattr(args, "images", []), "rectify": [getattr(args, "image", "")]}.get(args.command, [])
    if images and not any(Path(image).exists() for image in images):  # nothing to calibrate
        for image in images:
            print(f"ngp: error: {image}: file not found", file=sys.stderr)
        return 1
    return args


def run(args: argparse.Namespace) -> int:
    """Run the command of :func:`parse`'s arguments (importing the modules it needs); its exit status."""
    parser = _parser()
    if getattr(args, "weights", None) is not None:
        _check_weights(parser, args.command, args.weights)
    commands = {"calibrate": _calibrate, "predict": _predict, "rectify": _rectify, "demo": _demo}
    commands["render"] = render_command
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return commands[args.command](args)
    except KeyboardInterrupt:
        print("ngp: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # stop quietly, like other command-line tools, when the output is cut short
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except _user_errors() as err:
        print(f"ngp: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except Exception as err:  # a one-line message instead of a traceback, whatever went wrong
        print(f"ngp: error: {type(err).__name__}: {_one_line(err)}", file=sys.stderr)
        return 1


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """The package's warnings (:class:`~ngp_kornia.errors.NGPWarning`) as one line ``ngp: warning: <message>``;
    other warnings as Python shows them."""
    if issubclass(category, NGPWarning):
        print(f"ngp: warning: {_one_line(message)}", file=sys.stderr, flush=True)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ngp`` command: :func:`parse`, then :func:`run`."""
    args = parse(argv)
    return args if isinstance(args, int) else run(args)


if __name__ == "__main__":
    sys.exit(main())

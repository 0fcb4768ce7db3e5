"""dsr: direct simultaneous registration of several 3D images, from Python.

The C++ libraries do all the work (the module ``dsr._core``); this file turns Python
inputs into what they take. Options are keyword arguments from the options table the
command-line tools' flags come from (``max_iterations=50``, ``photometric="affine"``), with
their types, defaults, rules and one-line error messages: a bad value raises ``ValueError``
with the message the command line prints. ``help(dsr.register)`` lists them;
``dsr.options()`` gives the whole table.

Conventions (docs/design.md section 1): a pose is a 4x4 matrix T_i mapping world (frame 0's
physical space, LPS millimetres) to frame i; frame 0's is the identity. Arrays are indexed
[k, j, i] (numpy's and SimpleITK's order: the last axis is x).

Example::

    import dsr
    sequence = dsr.simulate(num_frames=4, seed=1)
    result = dsr.register(sequence.frames, masks=sequence.masks)
    print(result.summary["iterations"], result.poses[1])
    result.save("poses.json")
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Tuple, Union
from typing import Sequence as SequenceOf  # dsr.Sequence is the simulator's sequence

import numpy as np

from . import _core

__all__ = [
    "Image",
    "Result",
    "Sequence",
    "RegistrationError",
    "register",
    "fuse",
    "write_tfm",
    "simulate",
    "read_image",
    "write_image",
    "read_poses",
    "write_poses",
    "options",
]

RegistrationError = _core.RegistrationError
RegistrationError.__doc__ = (
    "A registration that was set up right but gave no result (dsr_register's exit status 1): "
    "a frame stuck in a wrong minimum, or a solve that diverged. The message says why.")


@dataclass
class Image:
    """A 3D image: ``array`` indexed [k, j, i] and its physical grid (LPS millimetres).

    ``direction`` is the 3x3 matrix whose columns are the index axes in physical space.
    ``read_image`` of a 4D file (one 3D volume per heart phase) gives an ``array`` indexed
    [t, k, j, i] with the phases' 3D grid; ``write_image`` writes such an array as a 4D file,
    and ``register`` and ``fuse`` take it as a view recorded over the heart cycle.
    """

    array: np.ndarray
    spacing: Tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))

    def geometry(self) -> Tuple[List[float], List[float], List[float]]:
        return (
            [float(v) for v in self.spacing],
            [float(v) for v in self.origin],
            [float(v) for v in np.asarray(self.direction, dtype=float).reshape(9)],
        )

    def to_simpleitk(self):
        """This image as a SimpleITK image (the same voxels, spacing, origin and direction;
        needs SimpleITK)."""
        import SimpleITK as sitk  # noqa: PLC0415 (only when asked for)

        if np.ndim(self.array) == 4:  # phases: a 4D image, 4th spacing 1 (as dsr writes it)
            return sitk.JoinSeries([Image(phase, self.spacing, self.origin,
                                          self.direction).to_simpleitk()
                                    for phase in self.array])
        image = sitk.GetImageFromArray(np.ascontiguousarray(self.array))
        image.SetSpacing([float(v) for v in self.spacing])
        image.SetOrigin([float(v) for v in self.origin])
        image.SetDirection([float(v) for v in np.asarray(self.direction, dtype=float).reshape(9)])
        return image

    @staticmethod
    def _from_core(pair) -> "Image":
        array, (spacing, origin, direction) = pair
        return Image(array, tuple(spacing), tuple(origin), np.asarray(direction).reshape(3, 3))


ImageLike = Union[str, "os.PathLike[str]", Image, np.ndarray, Any]


def _as_path(value: Any) -> Optional[str]:
    if isinstance(value, (str, os.PathLike)):
        return os.fspath(value)
    return None


def _as_image(value: Any, what: str) -> Image:
    """An Image from a dsr.Image, a SimpleITK image or a nibabel image."""
    if isinstance(value, Image):
        direction = np.asarray(value.direction, dtype=float)
        if direction.size != 9:
            raise ValueError(f"{what}: the direction needs 9 numbers (a 3x3 matrix), got "
                             f"shape {direction.shape}")
        return value
    if isinstance(value, np.ndarray):
        raise ValueError(
            f"{what}: a bare numpy array has no spacing, origin or direction; "
            "pass dsr.Image(array, spacing=..., origin=..., direction=...)")
    if hasattr(value, "GetSpacing") and hasattr(value, "GetDirection"):  # SimpleITK
        import SimpleITK as sitk  # noqa: PLC0415 (only when given one)

        if value.GetNumberOfComponentsPerPixel() > 1:
            raise ValueError(f"{what}: vector pixels ({value.GetNumberOfComponentsPerPixel()} "
                             "components per voxel); dsr registers images of scalar voxels")
        if value.GetDimension() != 3:
            raise ValueError(f"{what}: {value.GetDimension()}D image; dsr registers 3D images")
        return Image(
            sitk.GetArrayFromImage(value),
            tuple(value.GetSpacing()),
            tuple(value.GetOrigin()),
            np.asarray(value.GetDirection(), dtype=float).reshape(3, 3),
        )
    if hasattr(value, "affine") and hasattr(value, "get_fdata"):  # nibabel
        # nibabel's affine maps (i, j, k) to RAS; dsr's world is LPS (as ITK reads NIfTI).
        affine = np.diag([-1.0, -1.0, 1.0, 1.0]) @ np.asarray(value.affine, dtype=float)
        linear = affine[:3, :3]
        spacing = np.linalg.norm(linear, axis=0)
        data = np.asanyarray(value.dataobj)
        if data.ndim != 3:
            raise ValueError(f"{what}: {data.ndim}D data (shape {data.shape}); dsr registers 3D "
                             "images of scalar voxels")
        return Image(
            np.ascontiguousarray(np.transpose(data, (2, 1, 0))),
            tuple(spacing),
            tuple(affine[:3, 3]),
            linear / spacing,
        )
    raise ValueError(f"{what}: not a path, dsr.Image, SimpleITK image or nibabel image "
                     f"({type(value).__name__})")


def _inputs(images, masks, names):
    """What _core takes for images and masks: all paths, or all (array, geometry) pairs;
    and the images' names (default: the file names, or frame_NN)."""
    for given, what in ((images, "images"), (masks, "masks")):
        if isinstance(given, (str, bytes, os.PathLike)):
            raise TypeError(f"{what}: a sequence of images or paths, not one path ({given!r}); "
                            f"give a list: [{given!r}, ...]")
    images = list(images)
    paths = [_as_path(image) for image in images]
    mask_list = list(masks) if masks is not None else []
    if all(p is not None for p in paths):
        mask_paths = [_as_path(mask) for mask in mask_list]
        if any(p is None for p in mask_paths):
            raise ValueError("masks: give files with image files")
        core_images: list = paths
        core_masks: list = mask_paths
        default_names = [os.path.basename(p) for p in paths]
    else:
        if any(p is not None for p in paths):
            raise ValueError("images: give all as files or all as images, not both")
        core_images = []
        for i, image in enumerate(images):
            im = _as_image(image, f"image {i}")
            core_images.append((np.asarray(im.array), im.geometry()))  # _core casts to float32
        core_masks = []
        for i, mask in enumerate(mask_list):
            mk = _as_image(mask, f"mask {i}")
            core_masks.append((np.asarray(mk.array), mk.geometry()))  # non-zero = inside
        default_names = [f"frame_{i:02d}" for i in range(len(images))]
    for what, given in (("images", paths), ("masks", [_as_path(m) for m in mask_list])):
        for i, path in enumerate(given):
            if path is not None and "\0" in path:
                raise ValueError(f"{what}: the path of {what[:-1]} {i} contains a NUL character "
                                 f"({path!r}); a path ends there")
    if isinstance(names, (str, bytes)):
        raise TypeError(f"names: a sequence of names, one per image, not one name ({names!r})")
    image_names = list(names) if names is not None else default_names
    if len(image_names) != len(images):
        raise ValueError(f"names: {len(image_names)} names for {len(images)} images")
    if names is not None:
        first: Dict[str, int] = {}
        for i, name in enumerate(image_names):
            if not isinstance(name, str):
                raise ValueError(f"names: name {i} is not a string ({type(name).__name__})")
            if "\0" in name:
                raise ValueError(f"names: name {i} contains a NUL character ({name!r})")
            if name in first:
                raise ValueError(f"names: {name!r} is given twice (images {first[name]} and {i}); "
                                 "each image needs its own name (poses are matched to images "
                                 "by name)")
            first[name] = i
    return core_images, core_masks, image_names


def _flag_value(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))  # the shortest text that reads back as the same double
    if isinstance(value, (list, tuple)):
        return ",".join(_flag_value(v) for v in value)
    return os.fspath(value) if isinstance(value, os.PathLike) else str(value)


def _flags(options: Dict[str, Any]) -> List[Tuple[str, str]]:
    """The options as (name, text) pairs; ``flagfile=None`` (the signatures' default) is no
    flagfile."""
    return [(name, _flag_value(value)) for name, value in options.items()
            if not (name == "flagfile" and value is None)]


@dataclass
class Result:
    """A registration's result.

    ``poses``: one 4x4 array per frame (world = frame 0 -> frame i; frame 0's is the
    identity). ``summary``: mode, iterations, final cost, seconds, termination, recoveries,
    ``field_of_view``: which rule made the masks of images given without one;
    ``structure_fraction`` and ``pose_error_voxels``: per frame, the structure and
    determination checks' figures (docs/design.md 8.4, 8.7); ``photometric`` (with the
    default ``photometric="auto"``): which model the solves used, and why.
    ``gain``/``offset`` (with ``photometric="affine"``): frame i's corrected intensity is
    gain * I_i + offset. ``covariance``/``predicted_tre_mm`` (with ``uncertainty=True``).
    """

    poses: List[np.ndarray]
    summary: Dict[str, Any]
    images: List[str]
    gain: List[float]
    offset: List[float]
    covariance: List[np.ndarray]
    predicted_tre_mm: List[float]

    def save(self, path: Union[str, "os.PathLike[str]"]) -> None:
        """Writes the poses JSON dsr_register writes (atomically; OSError when it cannot,
        leaving no file)."""
        write_poses(path, self.poses, images=self.images, gain=self.gain, offset=self.offset,
                    covariance=self.covariance, predicted_tre_mm=self.predicted_tre_mm)


def register(images: SequenceOf[ImageLike],
             masks: Optional[SequenceOf[ImageLike]] = None,
             *,
             mode: str = "dsr",
             init: Union[str, "os.PathLike[str]"] = "auto",
             initial_poses: Optional[SequenceOf[np.ndarray]] = None,
             names: Optional[SequenceOf[str]] = None,
             on_iteration: Optional[Callable[[str, Dict[str, Any]], Any]] = None,
             progress_bar: bool = False,
             **options: Any) -> Result:
    """Registers several 3D images simultaneously, as ``dsr_register`` does.

    images: file paths (read as dsr_register reads them) or images (dsr.Image, SimpleITK,
        nibabel); frame 0 is the reference. A view recorded over the heart cycle is a 4D
        file or a dsr.Image whose array is (T, z, y, x): its phases share one pose and its
        mask (3D), every view with the same T phases; ``phases="0,2"`` picks some.
    masks: one field-of-view mask per image, the same kind as the images (a (T, z, y, x)
        array is taken as a 4D mask file is: when its phases are equal); default: each
        image's field of view by ``mask_rule`` ("hull": the convex hull of its non-zero
        voxels; "nonzero") eroded by ``mask_erosion`` voxels.
    mode, init, **options: the options of the options table that dsr_register takes as
        flags, by name (e.g. ``pyramid_levels=2``, ``photometric="affine"``,
        ``uncertainty=True``), with their defaults, rules and messages; ``dsr.options()``
        lists them (those with "python:register" among their front ends), and
        ``flagfile="run.flags"`` reads a flagfile as dsr_register does. Its iteration lines
        on stderr (``--progress``) are ``progress_bar`` and ``on_iteration`` here.
    initial_poses: start poses (4x4, world -> frame, one per image in the images' order)
        instead of ``init``'s, used as dsr_register uses an ``init`` poses file (with
        recovery).
    names: the images' names in the poses file, each its own (default: the file names, or
        frame_NN).
    on_iteration: called after every solver iteration as on_iteration(label, record) with
        record {"iteration", "cost", "step_norm", "seconds", "step_accepted"} and label the
        solve's (e.g. "level 1 dsr"); returning False stops the registration
        (RegistrationError), and an exception it raises is raised by register().
    progress_bar: a tqdm bar on stderr (tqdm must be installed): one step per iteration,
        the solve's label and cost beside it.

    Raises ValueError for bad input (the message dsr_register prints for it, e.g.
    "--max_iterations=0: must be >= 1" or "b.nii.gz: frame 1 has ...") and RegistrationError
    when the registration gives no result.
    """
    core_images, core_masks, image_names = _inputs(images, masks, names)
    callback = on_iteration
    bar = None
    if progress_bar:
        try:
            from tqdm.auto import tqdm  # noqa: PLC0415 (only when asked for)
        except ImportError as error:
            raise ImportError("progress_bar=True needs tqdm (pip install tqdm)") from error
        bar = tqdm(unit="it", desc="dsr")

        def callback(label: str, record: Dict[str, Any]) -> Any:
            bar.set_description(label, refresh=False)
            bar.set_postfix(cost=f"{record['cost']:.4g}", refresh=False)
            bar.update(1)
            return on_iteration(label, record) if on_iteration is not None else None

    start = None
    if initial_poses is not None:
        start = [np.asarray(pose, dtype=float) for pose in initial_poses]
    try:
        return _register(core_images, core_masks, image_names,
                         _flags({"mode": mode, "init": init, **options}),
                         start, callback)
    finally:
        if bar is not None:
            bar.close()


def _register(core_images, core_masks, image_names, flags, start, on_iteration) -> Result:
    observer = None
    if on_iteration is not None:
        def observer(label: str, record) -> bool:
            answer = on_iteration(label, {
                "iteration": record.iteration,
                "cost": record.cost,
                "step_norm": record.step_norm,
                "seconds": record.seconds,
                "step_accepted": record.step_accepted,
            })
            return answer is not False
    out = _core.register(core_images, core_masks, image_names, flags, start, observer)
    poses = out["poses"]
    return Result(
        poses=list(poses["frame_from_world"]),
        summary=dict(out["summary"]),
        images=list(poses["images"]),
        gain=list(poses["gain"]),
        offset=list(poses["offset"]),
        covariance=list(poses["covariance"]),
        predicted_tre_mm=list(poses["predicted_tre_mm"]),
    )


def fuse(images: SequenceOf[ImageLike],
         poses: Union[Result, SequenceOf[np.ndarray], str, "os.PathLike[str]"],
         masks: Optional[SequenceOf[ImageLike]] = None,
         *,
         blend: str = "feather",
         names: Optional[SequenceOf[str]] = None,
         **options: Any) -> Tuple[Image, Image]:
    """The panorama of the images at the poses, as ``dsr_fuse`` writes it: (mean, count),
    count being the number of frames that observe each voxel, as dsr.Image (numpy array and
    grid; ``.to_simpleitk()`` makes a SimpleITK image of each).

    poses: a Result (its gains and offsets correct the intensities, as dsr_fuse does with a
        poses file that has them), a poses file, or one 4x4 array per image (a list, a
        generator: any iterable). A file's or a Result's entries are matched to the images
        by name.
    blend: "feather" (weights falling to 0 towards each field of view's edge) or "mean".
    **options: the options dsr_fuse takes as flags, by name (``panorama_spacing``,
        ``feather_voxels``, ``mask_rule``, ``mask_erosion``, ``num_threads``).
    """
    core_images, core_masks, image_names = _inputs(images, masks, names)
    if isinstance(poses, Result):
        table = {"images": poses.images, "frame_from_world": poses.poses, "gain": poses.gain,
                 "offset": poses.offset}
    elif _as_path(poses) is not None:
        table = _as_path(poses)  # read and checked as dsr_fuse reads --poses
    else:
        try:
            given = list(poses)  # any iterable (a generator too), read once
        except TypeError as error:
            raise ValueError(f"poses: a Result, a poses file or one 4x4 array per image, not "
                             f"{type(poses).__name__}") from error
        matrices = []
        for i, pose in enumerate(given):
            try:
                matrices.append(np.asarray(pose, dtype=float))
            except (TypeError, ValueError) as error:
                raise ValueError(f"pose {i}: not a 4x4 array of numbers ({error})") from error
        table = {"images": [""] * len(matrices), "frame_from_world": matrices}
    mean, count, _ = _core.fuse(core_images, core_masks, image_names, table,
                                _flags({"blend": blend, **options}))
    return Image._from_core(mean), Image._from_core(count)


def write_tfm(pose: np.ndarray, path: Union[str, "os.PathLike[str]"]) -> None:
    """Writes a frame's pose (4x4, world -> frame) as the ITK transform file dsr_register
    writes for it (--out_tfm_dir), atomically (OSError when it cannot, leaving no file)."""
    _core.write_tfm(np.asarray(pose, dtype=float), os.fspath(path))


@dataclass
class Sequence:
    """A simulated sequence: frames and masks (dsr.Image) and the true poses (4x4, the
    source volume's physical space -> frame i), with the true gains and offsets when
    simulated (frame 0's scale, as Result.gain and Result.offset). With ``num_phases=T > 1`` (a
    beating source) ``phases[i][p]`` is view i at phase p of the heart cycle (``phases[i][0]``
    is ``frames[i]``; all phases of a view share its mask and pose); empty otherwise."""

    frames: List[Image]
    masks: List[Image]
    frame_from_world: List[np.ndarray]
    gain: List[float]
    offset: List[float]
    phases: List[List[Image]] = field(default_factory=list)

    def views(self) -> List[Image]:
        """The images ``register`` and ``fuse`` take: each view's phases as one (T, z, y, x)
        image (its phases stacked, the view's grid); without phases, the frames."""
        if not self.phases:
            return list(self.frames)
        return [Image(np.stack([p.array for p in view]), view[0].spacing, view[0].origin,
                      view[0].direction) for view in self.phases]


def simulate(**options: Any) -> Sequence:
    """Simulates a sequence as ``dsr_simulate`` does (the options it takes as flags, by name,
    e.g. ``seed=3``, ``num_frames=5``, ``source="volume.nii.gz"``; default: the built-in
    phantom and the paper's protocol), in memory."""
    out = _core.simulate(_flags(options))
    frames = [Image._from_core(f) for f in out["frames"]]
    return Sequence(
        frames=frames,
        masks=[Image._from_core(m) for m in out["masks"]],
        frame_from_world=list(out["frame_from_world"]),
        gain=list(out.get("gain", [])),
        offset=list(out.get("offset", [])),
        phases=[[frames[i]] + [Image._from_core(p) for p in view]
                for i, view in enumerate(out.get("later_phases", []))],
    )


def read_image(path: Union[str, "os.PathLike[str]"]) -> Image:
    """Reads a 3D image (NIfTI, MetaImage, NRRD) as dsr reads it (ITK, LPS). A 4D file of
    T > 1 phases (a NIfTI time axis, a NRRD list axis, 3D Slicer's .seq.nrrd; see
    docs/usage.md) gives an array of shape (T, z, y, x) and the phases' 3D grid."""
    return Image._from_core(_core.read_image(os.fspath(path)))


def write_image(image: ImageLike, path: Union[str, "os.PathLike[str]"]) -> None:
    """Writes a 3D image (float32; the format from the file name), atomically (OSError when
    it cannot, leaving no file). An array of shape (T, z, y, x) is written as T phases of
    one 3D grid: NIfTI with a time axis, NRRD with a list axis, and for ``.seq.nrrd`` the
    sequence file 3D Slicer loads as a sequence of scalar volumes (docs/usage.md)."""
    im = _as_image(image, "image")
    _core.write_image(np.asarray(im.array), im.geometry(), os.fspath(path))


def read_poses(path: Union[str, "os.PathLike[str]"], expected_frames: int = -1) -> Dict[str, Any]:
    """Reads a poses JSON (dsr_register's, dsr_simulate's gt_poses.json): a dict with
    "images", "frame_from_world" (4x4 arrays), "gain" and "offset" (empty when absent)."""
    return _core.read_poses(os.fspath(path), expected_frames)


def write_poses(path: Union[str, "os.PathLike[str]"],
                poses: SequenceOf[np.ndarray],
                *,
                images: Optional[SequenceOf[str]] = None,
                gain: SequenceOf[float] = (),
                offset: SequenceOf[float] = (),
                covariance: SequenceOf[np.ndarray] = (),
                predicted_tre_mm: SequenceOf[float] = ()) -> None:
    """Writes a poses JSON as dsr_register does (atomically; OSError when it cannot)."""
    poses = [np.asarray(p, dtype=float) for p in poses]
    _core.write_poses({
        "images": list(images) if images is not None else [""] * len(poses),
        "frame_from_world": poses,
        "gain": list(gain),
        "offset": list(offset),
        "covariance": [np.asarray(c, dtype=float) for c in covariance],
        "predicted_tre_mm": list(predicted_tre_mm),
    }, os.fspath(path))


def options() -> Dict[str, Dict[str, Any]]:
    """The options table, the one list every front end's options come from: name ->
    {type, default, group, front_ends, help, front_end_defaults}. register() takes those
    whose front_ends hold "python:register", fuse() "python:fuse", simulate()
    "python:simulate"; the command-line tools take theirs as --flags. front_end_defaults:
    where a front end's default differs from "default" (e.g. dsr_compare's checks are off,
    fuse() feathers)."""
    return {name: {"type": kind, "default": default, "group": group,
                   "front_ends": list(front_ends), "help": help_text,
                   "front_end_defaults": dict(own)}
            for name, kind, default, group, front_ends, help_text, own in _core.options()}


# The table's options as typed, documented keyword arguments of the functions that take
# them: their signatures (inspect.signature, help(), editors) and docstrings come from the
# options table, as the tools' --help and the docs' option reference do.
_PYTHON_TYPES = {"bool": bool, "int32": int, "int64": int, "uint64": int, "double": float,
                 "string": str}


def _option_default(kind: str, text: str) -> Any:
    if kind == "bool":
        return text.lower() in ("1", "t", "true", "y", "yes")
    if kind in ("int32", "int64", "uint64"):
        return int(text)
    if kind == "double":
        return float(text)
    return text


def _document_options(function: Callable[..., Any], front_end: str) -> None:
    import inspect  # noqa: PLC0415 (once, at import)

    signature = inspect.signature(function)
    explicit = [p for p in signature.parameters.values() if p.kind != p.VAR_KEYWORD]
    taken = {p.name for p in explicit}
    table = [(name, o) for name, o in options().items()
             if front_end in o["front_ends"] and name not in taken]
    keywords = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY,
                                  default=_option_default(
                                      o["type"], o["front_end_defaults"].get(front_end,
                                                                             o["default"])),
                                  annotation=_PYTHON_TYPES.get(o["type"], str))
                for name, o in table]
    flagfile = inspect.Parameter("flagfile", inspect.Parameter.KEYWORD_ONLY, default=None,
                                 annotation=Optional[str])
    function.__signature__ = signature.replace(parameters=explicit + keywords + [flagfile])
    lines = ["", "Options (the options table; dsr.options() lists them with their groups):", ""]
    for name, o in table:
        default = o["front_end_defaults"].get(front_end, o["default"])
        lines.append(f"    {name} ({o['type']}, default {default!r}): {o['help']}")
    lines.append("    flagfile (str): a flagfile of these options, read with the command "
                 "line's checks.")
    function.__doc__ = (function.__doc__ or "") + "\n".join(lines) + "\n"


_document_options(register, "python:register")
_document_options(fuse, "python:fuse")
_document_options(simulate, "python:simulate")

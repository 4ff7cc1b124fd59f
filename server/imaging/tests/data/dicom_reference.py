"""Reference values of the real DICOM series in data/ct/totalsegmentator-example/dicom,
decoded independently of cathlab (pydicom + pylibjpeg-openjpeg, the C OpenJPEG library).

    pip install pydicom pylibjpeg pylibjpeg-openjpeg numpy
    python3 server/imaging/tests/data/dicom_reference.py > server/imaging/tests/data/dicom_reference.json
"""
import glob
import json
import sys

import numpy as np
import pydicom

folder = sys.argv[1] if len(sys.argv) > 1 else "data/ct/totalsegmentator-example/dicom"
slices = [pydicom.dcmread(f) for f in glob.glob(folder + "/*")]
iop = np.array(slices[0].ImageOrientationPatient, dtype=float)
normal = np.cross(iop[:3], iop[3:])
slices.sort(key=lambda s: float(np.dot(normal, np.array(s.ImagePositionPatient, dtype=float))))
probes = [(256, 256), (100, 300), (400, 200), (10, 10), (300, 150)]
out = {
    "image_orientation_patient": [float(v) for v in iop],
    "pixel_spacing_mm": [float(v) for v in slices[0].PixelSpacing],
    "rows": int(slices[0].Rows),
    "columns": int(slices[0].Columns),
    "slices": [],
}
for s in slices:
    hu = s.pixel_array.astype(np.float64) * float(s.RescaleSlope) + float(s.RescaleIntercept)
    out["slices"].append({
        "image_position_patient_mm": [float(v) for v in s.ImagePositionPatient],
        "sum_hu": float(hu.sum()),
        "min_hu": float(hu.min()),
        "max_hu": float(hu.max()),
        # (column i, row j) -> HU
        "probes": [[i, j, float(hu[j, i])] for (i, j) in probes],
    })
json.dump(out, sys.stdout, indent=1)

"""Writes session.csv.gz, the simulated session the R files of this directory hold, and
session.f64, the same columns as raw little-endian float64 for R's readBin (exact: R's
read.csv may round a 17-digit value 1 ulp off).

Run from the repository root: python tests/data/rdata/make_session.py, then
Rscript tests/data/rdata/make_rdata.R (see README.md); session.f64 is not kept.
"""

from pathlib import Path

import numpy as np

from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.sim import Fault, multi_position, simulate

HERE = Path(__file__).parent

cert = load_default()
traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=50, seed=31)
lim = cert.accel.limits.scale_factor_error[2]
sim = simulate(cert, traj, seed=32, faults=[Fault("scale_factor", "az", 0.0, 4 * lim)])
s = sim.samples
with open_writer(HERE / "session.csv.gz", {"source": "imudiag.sim seed 32"}) as w:
    w.write(s)
# column after column: t gx gy gz ax ay az temp
cols = np.column_stack([s.t, s.gyro, s.accel, s.temp])
cols.T.astype("<f8").tofile(HERE / "session.f64")
print(len(s), "samples")

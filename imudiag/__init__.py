"""imudiag: onboard monitor and scalar diagnosis of a strapdown IMU.

Data flows one way: bytes -> frames -> samples -> monitor -> verdicts -> status.
"""

__version__ = "0.1.0"

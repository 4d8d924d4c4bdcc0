"""adfusion: star-camera attitude fixes fused with gyro and magnetometer data.

Example:
    >>> import adfusion
    >>> adfusion.__version__
    '0.1.0'
"""

__version__ = "0.1.0"

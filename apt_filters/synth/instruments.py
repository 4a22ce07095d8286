"""Detection efficiencies of common atom probe instruments (fraction of evaporated atoms detected)."""

DETECTION_EFFICIENCY: dict[str, float] = {
    "LEAP 5000S": 0.80,
    "LEAP 6000": 0.52,
    "LEAP 5000R": 0.52,
    "Invizio": 0.624,
    "EIKOS": 0.3575,
}
"""Instrument name -> detection efficiency (the synthetic default is 0.5)."""

"""Plasticity remedies (L2, RECOM) and diagnostics (dormant units, saturation, norms, srank)."""

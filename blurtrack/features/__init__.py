"""Natural-scene features: point tracks between consecutive frames (no laser target)."""

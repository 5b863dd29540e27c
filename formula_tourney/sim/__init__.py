"""The racing simulator: tracks, batched car physics, telemetry and the Gymnasium env."""

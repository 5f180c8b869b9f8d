"""Finding a phone's settings: calibration from a log or live samples (calibration), per-phone
profiles (profiles) and the auto-tune search against a reference (autotune)."""

"""Shared simulation overrides of the end-to-end tests (``simulate_to_dir(..., overrides=...)``)."""

#: a short ``open-track-gnss`` survey: 30 s static, 240 m out at 3 m/s, 10 s static, 140 m back at 2 m/s
SHORT_OPEN_TRACK = ["motion.passes=1",
                    "motion.segments=[{hold_s: 30}, {move_to_m: 260, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 10},"
                    " {move_to_m: 120, speed_mps: 2, accel_mps2: 0.4}]"]

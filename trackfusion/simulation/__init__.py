"""Survey simulation: everything that makes synthetic data -- track irregularity synthesis, trolley
motion, every sensor model (IMU, odometer, GNSS, total stations, inclinometer, gauge, vision), the
random error processes, fault injection -- and the scenario files that join them into logs and truth."""

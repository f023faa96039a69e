"""Survey simulation: truth motion of a trolley on irregular rails, sensor logs, truth files."""

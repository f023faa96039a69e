"""Registration: total-station polar observations, time synchronisation, multi-station registration."""

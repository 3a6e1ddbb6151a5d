"""Small shared helpers: devices, seeding, config access, torch rotations."""

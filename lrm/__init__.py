"""The module side of camcal: camera and sensors, schedule runner, outbox, simulator."""

# The camera: frames from a Pi camera, a USB webcam or the simulator, streamed and recorded.

"""Bundled model files: MediaPipe's Face Landmarker (``face_landmarker.task``, Apache-2.0;
see NOTICE and LICENSE-mediapipe in this folder)."""

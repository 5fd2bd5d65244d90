"""Frames in and rows out: one frame source for images, folders, videos, cameras, streams and recordings; live
estimation."""

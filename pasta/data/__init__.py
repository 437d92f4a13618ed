"""Datasets: trajectory storage and index (configuration generators and scripted skills come later)."""

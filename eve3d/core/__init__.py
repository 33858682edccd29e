"""The shared core: the scene and camera type, every setting, the method
registry, the results layout, file I/O and the dataset readers. Stages and the other
libraries build on it; it imports no stage."""

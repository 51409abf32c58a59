"""What an evaluation reads: the images and labels of ClaraVid, UAVid or a folder, saved label
maps, per-image metric CSVs, and frame pairs with their geometry."""

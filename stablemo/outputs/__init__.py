"""What a generated motion becomes on disk: file names from prompts, the .npy/BVH/animation files, stick-figure renders."""

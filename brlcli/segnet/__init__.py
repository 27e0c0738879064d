"""The EncNet-style segmentation net behind the paper's 'estimated' input: model, training, files, inference."""

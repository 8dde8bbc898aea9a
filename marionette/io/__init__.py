"""Reading and writing: 3DGS .ply, SpaT prior .npz, videos, images and masks."""

"""Makes image_metrics_case.npz: two small RGB images and their PSNR/SSIM by scikit-image.

SSIM settings are those of NeuroFluid's evaluation (D-NeRF's notebook): Gaussian window of
11 taps with sigma 1.5, population covariances, data range 1; scikit-image crops the 5-pixel
border of its (padded) SSIM map, which equals valid filtering.
Run: python3 make_image_metrics_case.py   (numpy, scikit-image; made with scikit-image 0.26.0)
"""
import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

rng = np.random.default_rng(7)
h, w = 20, 24
yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
a = np.stack([0.5 + 0.4 * np.sin(0.35 * xx + 0.2 * yy + c) for c in range(3)], axis=-1)
b = np.clip(a + rng.normal(0, 0.05, a.shape) + 0.03 * np.cos(0.5 * yy)[..., None], 0, 1)
a = a.astype(np.float32)
b = b.astype(np.float32)
ssim = structural_similarity(a.astype(np.float64), b.astype(np.float64), gaussian_weights=True,
                             sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1)
psnr = peak_signal_noise_ratio(a.astype(np.float64), b.astype(np.float64), data_range=1.0)
np.savez("image_metrics_case.npz", a=a, b=b, ssim=np.float64(ssim), psnr=np.float64(psnr))
print("ssim", ssim, "psnr", psnr)

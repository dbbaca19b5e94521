"""Image metrics: PSNR / SSIM (:mod:`~fracture_gs.metrics.image`), LPIPS (AlexNet), FID
(InceptionV3), fracture onset and the self-referenced fracture protocol of docs/formulas.md §14 (paper
App. A.3). Pretrained weights come from pip packages located on disk, never from a download;
see :mod:`fracture_gs.metrics.weights`."""

"""Files on disk and how to read them: the ClaraVid layout facts (``layout``), every modality's
decoder (``modalities``), the JPEG window decoder (``jpeg_region``, with its C extension), the
label codes and their tiled container (``labels``, ``label_tiff``), and YAML files
(``yamlfile``).

Knows nothing of datasets, palettes or splits; imports only ``claravid.infra``.
"""

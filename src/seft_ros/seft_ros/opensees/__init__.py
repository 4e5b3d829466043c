"""OpenSeesPy models as the computational substructure of a test (issue 32; no rclpy).

:mod:`~seft_ros.opensees.loader` loads OpenSeesPy (the Linux wheel's bundled BLAS first) and
keeps OpenSees' messages; :mod:`~seft_ros.opensees.model` reads a ``structure.opensees``
section, builds and checks the model and linearizes it; :mod:`~seft_ros.opensees.part` is
the computational part stepped by OpenSees once per sample; :mod:`~seft_ros.opensees.reference`
is OpenSees' own analysis of the whole structure; :mod:`~seft_ros.opensees.checks` refuses
runs that cannot run; :mod:`~seft_ros.opensees.report` is what the report says about the
model; :mod:`~seft_ros.opensees.plugin` is the plug-in the core loads by the section's key
(:mod:`seft_ros.core.models`): the core never imports this package. Docs: OpenSees models.
"""

__all__: list[str] = []

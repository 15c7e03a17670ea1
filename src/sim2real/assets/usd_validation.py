"""USD's own validation of the built asset: every registered ``pxr.UsdValidation`` validator (core, UsdGeom,
UsdShade, UsdSkel, UsdUtils and UsdPhysics), those that replace the removed ``UsdUtils.ComplianceChecker``'s
checks required (:data:`CLASSIC_CHECKS`)."""

from __future__ import annotations

from pathlib import Path

# usdz/ARKit packaging rules: this asset is a plain .usda pair, not a package.
PACKAGE_ONLY_VALIDATORS = frozenset({"usdUtilsValidators:UsdzPackageValidator", "usdUtilsValidators:RootPackageValidator"})


# Every check UsdUtils.ComplianceChecker (usdchecker's classic checks, removed in usd-core 26.8) made on
# a non-ARKit asset, and the registered UsdValidation validators that make it now. compliance_errors
# refuses a usd-core that lacks any of them, so no check is silently lost. The classic
# ByteAlignment/Compression checks apply to usdz packages only (PACKAGE_ONLY_VALIDATORS); the classic
# TextureChecker has no validator yet and nothing to check here (the writer authors no textures).
CLASSIC_CHECKS = {
    "StageMetadataChecker": ("usdValidation:StageMetadataChecker", "usdGeomValidators:StageMetadataChecker"),
    "MissingReferenceChecker": ("usdUtilsValidators:MissingReferenceValidator",),
    "PrimEncapsulationChecker": ("usdGeomValidators:EncapsulationChecker",
                                 "usdShadeValidators:EncapsulationRulesValidator"),
    "NormalMapTextureChecker": ("usdShadeValidators:NormalMapTextureValidator",),
    "MaterialBindingAPIAppliedChecker": ("usdShadeValidators:MaterialBindingApiAppliedValidator",),
    "SkelBindingAPIAppliedChecker": ("usdSkelValidators:SkelBindingApiAppliedValidator",),
    "ShaderPropertyTypeConformanceChecker": ("usdShadeValidators:ShaderSdrCompliance",),
}


# The UsdPhysics checks the classic checker never had.
PHYSICS_VALIDATORS = (
    "usdPhysicsValidators:ArticulationChecker", "usdPhysicsValidators:ColliderChecker",
    "usdPhysicsValidators:PhysicsJointChecker", "usdPhysicsValidators:RigidBodyChecker",
)


def validator_names() -> list[str]:
    """Every registered UsdValidation validator the asset is checked with (all but the usdz-package ones).

    Raises ``RuntimeError`` when the installed usd-core lacks a validator that replaces a classic check.
    """
    from pxr import UsdValidation

    registry = UsdValidation.ValidationRegistry()
    names = {str(m.name) for m in registry.GetAllValidatorMetadata() if not m.isSuite} - PACKAGE_ONLY_VALIDATORS
    required = {n for ns in CLASSIC_CHECKS.values() for n in ns} | set(PHYSICS_VALIDATORS)
    missing = sorted(required - names)
    if missing:
        raise RuntimeError(f"usd-core lacks the UsdValidation validators {', '.join(missing)}; "
                           "install the usd-core pyproject.toml asks for (pip install -e .)")
    return sorted(names)


def compliance_errors(usd_path: str | Path) -> list[str]:
    """Errors of USD's validation framework on a USD file and every layer it uses.

    Runs every registered ``pxr.UsdValidation`` validator (:func:`validator_names`: core, UsdGeom,
    UsdShade, UsdSkel, UsdUtils and UsdPhysics' articulation, joint, rigid-body and collider checks) on
    the stage, its used layers and every prim; each error as "<validator>.<error>: <message>".
    """
    from pxr import Usd, UsdValidation

    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadValidatorsByName(validator_names()))
    stage = Usd.Stage.Open(str(usd_path))
    return sorted(
        f"{error.GetIdentifier()}: {error.GetMessage()}"
        for error in context.Validate(stage)
        if error.GetType() == UsdValidation.ValidationErrorType.Error
    )

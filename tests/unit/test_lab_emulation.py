"""arm64 emulation for the lab: reading and writing binfmt_misc registrations."""

import pytest

DEBIAN_CONF = (
    r":qemu-aarch64:M::\x7f\x45\x4c\x46\x02\x01\x01\x00\x00\x00\x00\x00\x00\x00\x00\x00\x02\x00\xb7\x00"
    r":\xff\xff\xff\xff\xff\xff\xff\x00\xff\xff\xff\xff\xff\xff\xff\xff\xfe\xff\xff\xff"
    r":/usr/libexec/qemu-binfmt/aarch64-binfmt-P:OPF"
    "\n"
)
OURS = "/lab/cache/qemu/10/aarch64-binfmt-P"


def entry(flags="POCF", interpreter=OURS, enabled=True):
    return (
        "enabled\n" if enabled else "disabled\n"
    ) + f"interpreter {interpreter}\nflags: {flags}\noffset 0\nmagic 7f454c460201010000000000000000000200b700\n"


def test_the_kernel_lists_binfmt_misc_or_not(emulation):
    assert emulation.kernel_has_binfmt_misc("nodev\tsysfs\nnodev\tbinfmt_misc\n\text4\n")
    assert not emulation.kernel_has_binfmt_misc("nodev\tsysfs\n\text4\n")


def test_a_registration_is_read_from_its_proc_file(emulation):
    assert emulation.registration(entry()) == {"enabled": True, "interpreter": OURS, "flags": "POCF"}
    assert emulation.registration(entry(enabled=False))["enabled"] is False


def test_only_our_emulator_with_open_credentials_and_fix_binary_is_accepted(emulation):
    reg = emulation.registration
    assert emulation.problem(reg(entry()), OURS) is None
    assert emulation.problem(None, OURS) == "qemu-aarch64 is not registered with binfmt_misc"
    assert "disabled" in emulation.problem(reg(entry(enabled=False)), OURS)
    # Debian 12's update-binfmts registers qemu 7.2 with P and F only.
    assert emulation.problem(reg(entry("PF", "/usr/libexec/qemu-binfmt/aarch64-binfmt-P")), OURS) == (
        f"qemu-aarch64 runs /usr/libexec/qemu-binfmt/aarch64-binfmt-P, not {OURS}"
    )
    assert emulation.problem(reg(entry("PF")), OURS) == "qemu-aarch64 lacks the binfmt_misc flag(s) OC (has PF)"


def test_the_register_line_is_debians_with_our_emulator_and_credentials(emulation):
    line = emulation.register_line(DEBIAN_CONF, OURS)
    fields = line.split(":")
    assert fields[1:3] == ["qemu-aarch64", "M"] and fields[6] == OURS and fields[7] == "OPFC"
    assert line.startswith(DEBIAN_CONF.rsplit(":", 2)[0])  # Debian's magic and mask, untouched


def test_an_unexpected_package_line_is_one_error(emulation, engine):
    with pytest.raises(engine.LabError, match="unexpected binfmt line"):
        emulation.register_line(":qemu-arm:M::x:y:/bin/q:F", OURS)

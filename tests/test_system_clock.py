"""companion.system_clock against the kernel, asked by a C program of its own: glibc's
adjtimex() and struct timex, not our ctypes declaration of them."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from fpv_station.companion.system_clock import clock_synchronised

PROGRAM = r"""
#include <stdio.h>
#include <sys/timex.h>
int main(void) {
    struct timex t = {0};  /* modes 0: only read */
    int state = adjtimex(&t);
    if (state < 0) { perror("adjtimex"); return 1; }
    printf("%d\n", state != TIME_ERROR);
    return 0;
}
"""


def test_clock_synchronised_says_what_the_kernel_says(tmp_path) -> None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler here to ask the kernel independently")
    (tmp_path / "sync.c").write_text(PROGRAM)
    subprocess.run([cc, "-o", str(tmp_path / "sync"), str(tmp_path / "sync.c")], check=True)
    kernel = subprocess.run([str(tmp_path / "sync")], capture_output=True, text=True, check=True)
    assert clock_synchronised() is (kernel.stdout.strip() == "1")

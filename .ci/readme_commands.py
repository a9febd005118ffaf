"""Every command the README shows, as a script to run in a fresh clone (a session's check).

``python .ci/readme_commands.py README.md CLONE`` writes ``CLONE/../run.sh`` (each line of the
README's ``bash`` blocks, comments and blank lines left out, run from ``CLONE`` in one shell and
followed by an ``echo "rc=$? :: <line>"``) and ``CLONE/../readme.py`` (the ``python`` blocks in
order, run by the last line of ``run.sh``). Run ``bash run.sh > run.log 2>&1`` and look for a
line ``rc=`` that is not ``rc=0``. The clone needs ``../shared`` beside it as CI has it. Not
part of ``.ci/run``: the README's set-up lines create virtual environments and install the
package, which take minutes.
"""

import re
import sys
from pathlib import Path


def main(readme: str, clone: str) -> None:
    text = Path(readme).read_text()
    clone_dir = Path(clone).resolve()
    sh, py = ["set +e", f"cd {clone_dir}"], []
    for lang, body in re.findall(r"```(\w*)\n(.*?)```", text, re.S):
        if lang == "bash":
            for line in body.splitlines():
                if line.strip() and not line.strip().startswith("#"):
                    shown = line.replace('"', "'").replace("$", "\\$").replace("`", "'")
                    sh += [line, f'echo "rc=$? :: {shown}"']
        elif lang == "python":
            py.append(body)
    script = clone_dir.parent / "readme.py"
    sh.append(f'python {script}; echo "rc=$? :: python blocks"')
    (clone_dir.parent / "run.sh").write_text("\n".join(sh) + "\n")
    script.write_text("\n".join(py))
    print(f"{len(sh) // 2} shell lines, {len(py)} python blocks -> {clone_dir.parent}/run.sh")


if __name__ == "__main__":
    main(*sys.argv[1:3])

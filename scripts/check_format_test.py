#!/usr/bin/env python3
"""Tests of scripts/check_format.py: the changed lines read from a patch, the column rule,
and, in a scratch git repository with the project's .clang-format, a change laid out by
hand refused and the same change laid out by clang-format accepted, with the code before
the base left alone. Run by scripts/lint.sh: python3 scripts/check_format_test.py
"""
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import unittest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import check_format  # noqa: E402 (after the path above)

PATCH = """\
diff --git a/a.cc b/a.cc
index 1..2 100644
--- a/a.cc
+++ b/a.cc
@@ -3,0 +4,2 @@ int f() {
+  int x = 1;
+  return x;
@@ -10 +12 @@ int g() {
-  return 0;
+  return 1;
@@ -20,3 +21,0 @@ int h() {
-  a();
-  b();
-  c();
diff --git a/old.h b/new.h
similarity index 90%
rename from old.h
rename to new.h
--- a/old.h
+++ b/new.h
@@ -7 +7 @@
-int y;
+int z;
diff --git a/gone.cc b/gone.cc
deleted file mode 100644
--- a/gone.cc
+++ /dev/null
@@ -1,2 +0,0 @@
-int a;
-int b;
"""


class ChangedLines(unittest.TestCase):
    def test_added_and_changed_lines_in_the_new_numbering(self):
        self.assertEqual(check_format.changed_lines(PATCH),
                         {"a.cc": [(4, 5), (12, 12)], "new.h": [(7, 7)]})

    def test_a_patch_without_files_changes_nothing(self):
        self.assertEqual(check_format.changed_lines(""), {})


class LongLines(unittest.TestCase):
    def test_lines_over_the_limit_are_named(self):
        text = "x" * 100 + "\n" + "y" * 101 + "\n"
        self.assertEqual(check_format.long_lines(["f.cc"], read=lambda p: text),
                         ["f.cc:2: 101 columns (at most 100)"])


@unittest.skipUnless(shutil.which("clang-format"), "clang-format is not installed")
class InAScratchRepository(unittest.TestCase):
    def run_git(self, *args):
        subprocess.run(["git", *args], cwd=self.root, check=True, capture_output=True)

    def check(self, base):
        return subprocess.run([sys.executable, str(HERE / "check_format.py"), base],
                              cwd=self.root, capture_output=True, text=True)

    def setUp(self):
        self.root = pathlib.Path(tempfile.mkdtemp(prefix="check_format_test"))
        self.addCleanup(shutil.rmtree, self.root)
        shutil.copy(HERE.parent / ".clang-format", self.root / ".clang-format")
        self.run_git("init", "-q")
        self.run_git("config", "user.email", "t@example.org")
        self.run_git("config", "user.name", "t")
        # Laid out by hand, not as clang-format would: before the base, so left alone.
        (self.root / "a.cc").write_text("int f( int x ) { return x; }\n\nint g() {\n"
                                        "  int y = 0;\n  return y;\n}\n")
        self.run_git("add", ".")
        self.run_git("commit", "-q", "-m", "base")

    def test_code_before_the_base_is_left_alone(self):
        run = self.check("HEAD")
        self.assertEqual(run.returncode, 0, run.stdout + run.stderr)

    def test_a_changed_line_must_be_laid_out_as_clang_format_says(self):
        path = self.root / "a.cc"
        path.write_text(path.read_text().replace("  return y;", "  return   y ;"))
        run = self.check("HEAD")
        self.assertEqual(run.returncode, 1, run.stdout + run.stderr)
        self.assertIn("a.cc:5: not laid out as .clang-format says", run.stdout)
        path.write_text(path.read_text().replace("  return   y ;", "  return y + 1;"))
        self.assertEqual(self.check("HEAD").returncode, 0)

    def test_a_line_over_100_columns_is_refused_anywhere(self):
        (self.root / "b.h").write_text("// " + "w" * 98 + "\n")
        self.run_git("add", "b.h")
        self.run_git("commit", "-q", "-m", "long")
        run = self.check("HEAD")
        self.assertEqual(run.returncode, 1)
        self.assertIn("b.h:1: 101 columns", run.stdout)

    def test_a_file_git_does_not_track_yet_counts_whole(self):
        (self.root / "c.cc").write_text("int h( ) { return 2 ; }\n")
        run = self.check("HEAD")
        self.assertEqual(run.returncode, 1, run.stdout + run.stderr)
        self.assertIn("c.cc:1: not laid out", run.stdout)
        (self.root / "c.cc").write_text("int h() { return 2; }\n")
        self.assertEqual(self.check("HEAD").returncode, 0)

    def test_an_unknown_base_is_an_error_of_its_own(self):
        self.assertEqual(self.check("0" * 40).returncode, 2)


if __name__ == "__main__":
    os.environ.setdefault("GIT_CONFIG_NOSYSTEM", "1")
    unittest.main()

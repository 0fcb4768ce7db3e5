"""Tests of docs/gen_options.py (standard library; scripts/docs.sh runs them):
python3 -m unittest docs/gen_options_test.py. Where the docs' Markdown package is installed
(.venv-docs), the generated page is also rendered the way the site renders it."""

import html
import io
import json
import os
import re
import sys
import tempfile
import unittest
from contextlib import redirect_stderr
from unittest import mock

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gen_options

try:
    import markdown
except ImportError:
    markdown = None

NASTY = "a | b < c > d & e *f* _g_ `h` $i$ [j](k) l\\m"


def option(name, group="Solver", **fields):
    entry = {"name": name, "type": "int32", "default": "1", "help": f"Help of {name}.",
             "group": group, "front_ends": ["dsr_register", "python:register"]}
    entry.update(fields)
    return entry


TABLE = [
    option("max_iterations", default="100"),
    option("images", group="Input and output", type="string", default="",
           front_ends=["dsr_register", "dsr_fuse"]),
    option("mode", type="string", default="dsr|dba", help=NASTY),
    option("seed", group="Simulation", type="uint64", front_ends=["python:simulate"]),
    option("step_tolerance", type="double", default="1e-06"),
    option("uncertainty", group="Input and output", type="bool", default="false",
           help="Two\nlines."),
]


def cells(row):
    """A table row's cells, split the way Markdown's tables split them (at | not escaped)."""
    return re.split(r"(?<!\\)\|", row.strip().strip("|"))


class RenderTest(unittest.TestCase):
    def setUp(self):
        self.text = gen_options.render(TABLE)
        self.lines = self.text.splitlines()

    def test_every_option_appears_once(self):
        for entry in TABLE:
            rows = [line for line in self.lines if line.startswith(f"| `--{entry['name']}`")
                    or line.startswith(f"| `{entry['name']}=`")]
            self.assertEqual(len(rows), 1, entry["name"])

    def test_one_section_per_group_in_order_of_first_appearance(self):
        headings = [line[3:] for line in self.lines if line.startswith("## ")]
        self.assertEqual(headings, ["Solver", "Input and output", "Simulation"])

    def test_options_sit_under_their_group_in_table_order(self):
        section = None
        seen = {}
        for line in self.lines:
            if line.startswith("## "):
                section = line[3:]
            match = re.match(r"\| `(?:--)?([a-z_]+)=?`", line)
            if match:
                seen.setdefault(section, []).append(match.group(1))
        self.assertEqual(seen, {
            "Solver": ["max_iterations", "mode", "step_tolerance"],
            "Input and output": ["images", "uncertainty"],
            "Simulation": ["seed"]})

    def test_rows_have_five_cells_whatever_the_text(self):
        rows = [line for line in self.lines if line.startswith("| `")]
        self.assertEqual(len(rows), len(TABLE))
        for row in rows:
            self.assertEqual(len(cells(row)), 5, row)

    def test_escaping_leaves_no_markdown_or_html_syntax(self):
        escaped = gen_options.escape(NASTY)
        for c in "|<>*_`$[]\\":
            self.assertNotIn(c, escaped)
        self.assertEqual(html.unescape(escaped), NASTY)
        self.assertIn(escaped, self.text)

    def test_help_is_one_line(self):
        self.assertIn("| Two lines. |", self.text)

    def test_flag_and_keyword_follow_the_front_ends(self):
        self.assertIn("| `--max_iterations`<br>`max_iterations=` |", self.text)
        self.assertIn("| `--images` |", self.text)
        self.assertIn("| `seed=` |", self.text)

    def test_defaults(self):
        self.assertIn('<code>""</code>', self.text)  # images: an empty string
        self.assertIn("<code>dsr&#124;dba</code>", self.text)
        self.assertIn("<code>100</code>", self.text)


class ValidateTest(unittest.TestCase):
    def assert_refused(self, table, message):
        with self.assertRaisesRegex(gen_options.TableError, message):
            gen_options.render(table)

    def test_refuses_a_malformed_table(self):
        self.assert_refused({"name": "x"}, "JSON array")
        self.assert_refused([option("a"), option("a")], "declared twice")
        entry = option("a")
        del entry["help"]
        self.assert_refused([entry], 'no "help"')
        self.assert_refused([option("a", default=100)], '"default" must be a JSON str')
        self.assert_refused([option("a", front_ends="dsr_register")], '"front_ends"')
        self.assert_refused([option("a b")], "letters, digits")
        self.assert_refused([option("a", group=" ")], "empty")


class MainTest(unittest.TestCase):
    def test_reads_a_file_or_stdin_and_writes_the_page(self):
        with tempfile.TemporaryDirectory() as folder:
            table = os.path.join(folder, "options.json")
            with open(table, "w", encoding="utf-8") as f:
                json.dump(TABLE, f)
            out = os.path.join(folder, "options.md")
            self.assertEqual(gen_options.main([table, "--out", out]), 0)
            with open(out, encoding="utf-8") as f:
                from_file = f.read()
            with mock.patch("sys.stdin", io.StringIO(json.dumps(TABLE))):
                self.assertEqual(gen_options.main(["--out", out]), 0)
            with open(out, encoding="utf-8") as f:
                self.assertEqual(f.read(), from_file)
            self.assertEqual(from_file, gen_options.render(TABLE))

    def test_bad_input_is_one_error_line_and_exit_2(self):
        with tempfile.TemporaryDirectory() as folder:
            table = os.path.join(folder, "options.json")
            with open(table, "w", encoding="utf-8") as f:
                f.write("[{")
            stderr = io.StringIO()
            with redirect_stderr(stderr):
                status = gen_options.main([table, "--out", os.path.join(folder, "o.md")])
            self.assertEqual(status, 2)
            self.assertEqual(len(stderr.getvalue().splitlines()), 1)
            self.assertFalse(os.path.exists(os.path.join(folder, "o.md")))


@unittest.skipIf(markdown is None, "the Markdown package is not installed (.venv-docs has it)")
class RenderedTest(unittest.TestCase):
    def test_the_site_shows_the_text_as_written(self):
        page = markdown.markdown(gen_options.render(TABLE), extensions=["tables"])
        rows = re.findall(r"<tr>(.*?)</tr>", page, re.S)
        self.assertEqual(len(rows), len(TABLE) + 3)  # one header row per group
        mode = next(r for r in rows if "--mode" in r)
        help_cell = re.findall(r"<td>(.*?)</td>", mode, re.S)[-1]
        self.assertEqual(html.unescape(help_cell), NASTY)
        self.assertNotIn("<em>", page)
        self.assertNotIn("<a ", page)


if __name__ == "__main__":
    unittest.main()

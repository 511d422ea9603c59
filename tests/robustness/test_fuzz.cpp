// A seeded fuzzer of project.json and checkpoint.json: every mutant is refused with one line
// naming the file, or accepted; none crashes or hangs.
#include <doctest/doctest.h>

#include <fstream>
#include <functional>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>

#include "robustness/robust_util.h"
#include "test_util.h"
#include "util/fs.h"

using namespace refocus;
using namespace refocus::test;
using namespace refocus::robust;
using nlohmann::json;

namespace {

// Random edits of a JSON document: fields deleted, duplicated, retyped, made huge, nested deep,
// turned into format strings; then the text cut, spliced or given a NaN.
class Mutator {
  public:
    explicit Mutator(unsigned seed) : rng(seed) {}
    size_t pick(size_t n) { return std::uniform_int_distribution<size_t>(0, n - 1)(rng); }
    std::string operator()(json doc);

  private:
    std::mt19937 rng;
    const std::vector<json> odd = {nullptr,
                                   true,
                                   -1,
                                   0,
                                   4294967297LL,
                                   -2147483648LL,
                                   1e308,
                                   -1e308,
                                   18446744073709551615ULL,
                                   0.5,
                                   "",
                                   "%n%s%hhn%99999d",
                                   "x';touch INJECTED;'",
                                   "../../etc/passwd",
                                   std::string(5000, 'a'),
                                   json::array(),
                                   json::object(),
                                   json::array({1, "a", nullptr})};
    // Every (object, key) / (array, index) place in a document.
    static void places(json& j, std::vector<json*>& out) {
        out.push_back(&j);
        if (j.is_object())
            for (auto& [k, v] : j.items()) places(v, out);
        else if (j.is_array())
            for (auto& v : j) places(v, out);
    }
};

std::string Mutator::operator()(json doc) {
    const int n = 1 + int(pick(3));
    for (int m = 0; m < n; ++m) {
        std::vector<json*> all;
        places(doc, all);
        json& v = *all[pick(all.size())];
        switch (pick(8)) {
            case 0:  // delete a field
                if (v.is_object() && !v.empty()) {
                    auto it = v.begin();
                    std::advance(it, pick(v.size()));
                    v.erase(it.key());
                }
                break;
            case 1:  // duplicate a field under another name / append
                if (v.is_object() && !v.empty())
                    v["copy_" + std::to_string(pick(100))] = v.begin().value();
                else if (v.is_array())
                    v.push_back(v.empty() ? json(1) : v[0]);
                break;
            case 2:
            case 3:
                v = odd[pick(odd.size())];
                break;  // type / range change
            case 4:     // numbers: huge, negative, fractional
                if (v.is_number())
                    v = v.get<double>() * (pick(2) ? -1.0 : 1e12) + (pick(2) ? 0.5 : 0.0);
                else
                    v = -7;
                break;
            case 5: {  // deep nesting
                json d = v;
                for (int k = 0, depth = 60 + int(pick(20)); k < depth; ++k) d = json::array({d});
                v = d;
                break;
            }
            case 6:
                v = "%" + std::string(1, "dnsxhp%"[pick(7)]) + "\"'" + std::to_string(pick(9));
                break;
            default:
                v = json::object({{"x", v}});
                break;
        }
    }
    std::string text = doc.dump(pick(2) ? 2 : -1);
    const size_t t = pick(12);
    if (t == 0)
        text = text.substr(0, pick(text.size()));  // truncated
    else if (t == 1)
        text.insert(pick(text.size()), 1, "{[\",:\\NaN"[pick(9)]);
    else if (t == 2)
        text.replace(text.find(':') + 1, 0, " NaN,");
    return text;
}

// Counts outcomes by exit status: 124/137 a hang, >= 128 a crash, 0 accepted, else a refusal
// that must be one line naming the file.
struct Tally {
    int crashes = 0, hangs = 0, unclear = 0, ok = 0;
    void add(int rc, bool clear, const fs::path& file, const std::string& out) {
        if (rc == 124 || rc == 137)
            ++hangs;
        else if (rc >= 128)
            ++crashes;
        else if (rc == 0)
            ++ok;
        else if (!clear)
            ++unclear;
        if (rc != 0 && (rc >= 124 || !clear))
            MESSAGE("rc " << rc << " for " << file.string() << ": " << out);
    }
    void check(const std::string& what, int n) const {
        MESSAGE(what << ": " << n << ", accepted " << ok << ", crashes " << crashes << ", hangs "
                     << hangs << ", unclear errors " << unclear);
        CHECK(crashes == 0);
        CHECK(hangs == 0);
        CHECK(unclear == 0);
    }
};

// Each mutant directory's rc.txt and out.txt, as the xargs runs leave them.
std::pair<int, std::string> outcome_of(const fs::path& d) {
    return {std::stoi(read_text_file(d / "rc.txt")), read_text_file(d / "out.txt")};
}

constexpr int kProject = 320;
constexpr int kCheckpoint = 16;

// Every mutant is loaded as `refocus info` loads it, in a forked child (a crash or a hang is
// seen as such); every 8th is listed for the CLI itself (a process start costs ~0.7 s).
void fuzz_project_in_child(const Clip& c, const fs::path& work, const json& base, Mutator& mutate) {
    const fs::path frames = fs::absolute(c.project / "frames");
    std::ostringstream script;
    Tally tally;
    for (int i = 0; i < kProject; ++i) {
        const fs::path d = work / ("p" + std::to_string(i));
        fs::create_directories(d);
        fs::create_directory_symlink(frames, d / "frames");
        std::ofstream(d / "project.json") << mutate(base);
        if (i % 8 == 0) script << q(d.string()) << "\n";
        const Outcome o = load_in_child(d, 20);
        tally.add(o.rc, one_line_naming(o.out, "project.json"), d / "project.json", o.out);
    }
    tally.check("project.json mutants (in a child)", kProject);
    std::ofstream(work / "list.txt") << script.str();
}

// The listed mutants through `refocus info`, two at a time, each under a timeout.
void fuzz_project_cli(const fs::path& work) {
    RunResult r =
        run("cd " + q(work.string()) + " && xargs -P 2 -I{} sh -c 'timeout -k 2 20 " + REFOCUS_CLI +
            " info \"$1\" > \"$1/out.txt\" 2>&1; echo $? > \"$1/rc.txt\"' _ {} < list.txt");
    REQUIRE(r.code == 0);
    Tally tally;
    for (int i = 0; i < kProject; i += 8) {
        const fs::path d = work / ("p" + std::to_string(i));
        const auto [rc, out] = outcome_of(d);
        tally.add(rc, one_line_naming(out, "project.json"), d / "project.json", out);
    }
    tally.check("project.json mutants (CLI)", kProject / 8);
    CHECK(!fs::exists(work / "INJECTED"));
}

// checkpoint.json: export one frame from a copy of the fitted project (the costly part).
void fuzz_checkpoints(const Clip& c, const fs::path& work, const json& base, Mutator& mutate) {
    const json ckpt = json::parse(read_text_file(c.project / "fit" / "checkpoint.json"));
    std::ostringstream list2;
    for (int i = 0; i < kCheckpoint; ++i) {
        const fs::path d = work / ("c" + std::to_string(i));
        fs::create_directories(d / "fit");
        for (const auto& e : fs::directory_iterator(c.project))
            if (e.path().filename() != "fit" && e.path().filename() != ".lock" &&
                e.path().filename() != "project.json")
                fs::create_symlink(fs::absolute(e.path()), d / e.path().filename());
        json pj = base;  // the radius maps' path is relative to the project: made absolute here
        pj["fit"]["coc"] = fs::absolute(c.clip / "coc_%04d.exr").string();
        std::ofstream(d / "project.json") << pj.dump(2);
        for (const auto& e : fs::directory_iterator(c.project / "fit"))
            if (e.path().filename() != "checkpoint.json")
                fs::create_symlink(fs::absolute(e.path()), d / "fit" / e.path().filename());
        std::ofstream(d / "fit" / "checkpoint.json") << mutate(ckpt);
        list2 << q(d.string()) << "\n";
    }
    std::ofstream(work / "list2.txt") << list2.str();
    RunResult r = run(
        "cd " + q(work.string()) + " && xargs -P 2 -I{} sh -c 'timeout -k 2 60 " + REFOCUS_CLI +
        " export \"$1\" --what sharp --last 0 --out \"$1/out\" > \"$1/out.txt\" 2>&1; echo $? > "
        "\"$1/rc.txt\"' _ {} < list2.txt");
    REQUIRE(r.code == 0);
    Tally tally;
    for (int i = 0; i < kCheckpoint; ++i) {
        const fs::path d = work / ("c" + std::to_string(i));
        const auto [rc, out] = outcome_of(d);
        tally.add(rc, count_lines_with(out, "error:") == 1, d / "fit" / "checkpoint.json", out);
    }
    tally.check("checkpoint.json mutants", kCheckpoint);
}

}  // namespace

TEST_CASE("fuzzed project.json and checkpoint.json: no crash, no hang, one line naming the file") {
    const Clip& c = fitted("fuzz_fitted");
    const fs::path work = scratch_dir("robust_fuzz");
    const json base = json::parse(read_text_file(c.project / "project.json"));
    Mutator mutate(20240538);
    fuzz_project_in_child(c, work, base, mutate);
    fuzz_project_cli(work);
    fuzz_checkpoints(c, work, base, mutate);
}

// A seeded fuzzer of project.json, checkpoint.json, the checkpoint's tensor file and the input's
// pixel values: every mutant is refused with one line naming the file, or accepted; none crashes
// or hangs, and no export holds a non-finite pixel.
#include <doctest/doctest.h>

#include <fstream>
#include <functional>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>

#include "fit/fit_engine.h"
#include "io/image_file.h"
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
constexpr int kTensorFiles = 8;
constexpr int kPixelClips = 6;

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

// A copy of the fitted project at `d` whose files are links to the original's, but for
// project.json (the base, with the radius maps' path made absolute) and an empty fit/.
void mutant_project(const Clip& c, const fs::path& d, const json& base) {
    fs::create_directories(d / "fit");
    for (const auto& e : fs::directory_iterator(c.project))
        if (e.path().filename() != "fit" && e.path().filename() != ".lock" &&
            e.path().filename() != "project.json")
            fs::create_symlink(fs::absolute(e.path()), d / e.path().filename());
    json pj = base;
    pj["fit"]["coc"] = fs::absolute(c.clip / "coc_%04d.exr").string();
    std::ofstream(d / "project.json") << pj.dump(2);
}

// Exports one frame of each listed project, two at a time, each under a timeout; each leaves
// out.txt and rc.txt in its folder.
void export_each(const fs::path& work, const std::string& list_name, const std::string& list) {
    std::ofstream(work / list_name) << list;
    RunResult r = run(
        "cd " + q(work.string()) + " && xargs -P 2 -I{} sh -c 'timeout -k 2 60 " + REFOCUS_CLI +
        " export \"$1\" --what sharp --last 0 --out \"$1/out\" > \"$1/out.txt\" 2>&1; echo $? > "
        "\"$1/rc.txt\"' _ {} < " +
        list_name);
    REQUIRE(r.code == 0);
}

// checkpoint.json: export one frame from a copy of the fitted project (the costly part).
void fuzz_checkpoints(const Clip& c, const fs::path& work, const json& base, Mutator& mutate) {
    const json ckpt = json::parse(read_text_file(c.project / "fit" / "checkpoint.json"));
    std::ostringstream list2;
    for (int i = 0; i < kCheckpoint; ++i) {
        const fs::path d = work / ("c" + std::to_string(i));
        mutant_project(c, d, base);
        for (const auto& e : fs::directory_iterator(c.project / "fit"))
            if (e.path().filename() != "checkpoint.json")
                fs::create_symlink(fs::absolute(e.path()), d / "fit" / e.path().filename());
        std::string text = mutate(ckpt);
        // Every other mutant carries a checksum of its own fields, so that the validation of
        // each field is reached too (the checksum alone would refuse them all).
        if (i % 2 == 0) {
            const json m = json::parse(text, nullptr, false);
            if (m.is_object()) {
                json signed_m = m;
                signed_m["checksum"] = FitEngine::checkpoint_json_checksum(m);
                text = signed_m.dump(1);
            }
        }
        std::ofstream(d / "fit" / "checkpoint.json") << text;
        list2 << q(d.string()) << "\n";
    }
    export_each(work, "list2.txt", list2.str());
    Tally tally;
    for (int i = 0; i < kCheckpoint; ++i) {
        const fs::path d = work / ("c" + std::to_string(i));
        const auto [rc, out] = outcome_of(d);
        tally.add(rc, count_lines_with(out, "error:") == 1, d / "fit" / "checkpoint.json", out);
    }
    tally.check("checkpoint.json mutants", kCheckpoint);
}

// The checkpoint's tensor file: bytes flipped, zeroed, cut or duplicated; every mutant is
// refused with one line naming the file (the checksum), none crashes or exports.
void fuzz_tensor_files(const Clip& c, const fs::path& work, const json& base, std::mt19937& rng) {
    const json ckpt = json::parse(read_text_file(c.project / "fit" / "checkpoint.json"));
    const std::string pt_name = ckpt["tensors"].get<std::string>();
    const std::string bytes = read_text_file(c.project / "fit" / pt_name);
    std::ostringstream list;
    for (int i = 0; i < kTensorFiles; ++i) {
        const fs::path d = work / ("t" + std::to_string(i));
        mutant_project(c, d, base);
        fs::copy_file(c.project / "fit" / "checkpoint.json", d / "fit" / "checkpoint.json");
        for (const auto& e :
             fs::directory_iterator(c.project / "fit"))  // the checkpoint's other files
            if (e.path().filename() != "checkpoint.json" && e.path().filename() != pt_name)
                fs::create_symlink(fs::absolute(e.path()), d / "fit" / e.path().filename());
        std::string m = bytes;
        auto at = [&] { return std::uniform_int_distribution<size_t>(0, m.size() - 1)(rng); };
        switch (i % 4) {
            case 0:  // scattered flips
                for (int k = 0; k < 1 + int(at() % 2000); ++k) m[at()] ^= char(1 + at() % 255);
                break;
            case 1:  // a zeroed run
                std::fill_n(m.begin() + std::min(at(), m.size() - 64), 64, '\0');
                break;
            case 2:  // cut
                m.resize(at());
                break;
            default:  // one bit
                m[at()] ^= 1;
                break;
        }
        std::ofstream(d / "fit" / pt_name, std::ios::binary) << m;
        list << q(d.string()) << "\n";
    }
    export_each(work, "list3.txt", list.str());
    Tally tally;
    for (int i = 0; i < kTensorFiles; ++i) {
        const fs::path d = work / ("t" + std::to_string(i));
        const auto [rc, out] = outcome_of(d);
        tally.add(rc, one_line_naming(out, pt_name), d / "fit" / pt_name, out);
        CHECK(rc != 0);  // a damaged archive never exports
    }
    tally.check("tensor file mutants", kTensorFiles);
}

// Input frames with extreme values (finite and not) at random places: `new` refuses them with
// one line naming the frame, or with --nonfinite clean ingests them; a fit of a cleaned clip
// exports no non-finite pixel.
void fuzz_pixels(const fs::path& work, std::mt19937& rng) {
    const float extremes[] = {1e30f, -1e30f, 65504.0f, 1e5f, -3e4f, 1e-40f, NAN, INFINITY};
    Tally refused, cleaned;
    for (int i = 0; i < kPixelClips; ++i) {
        const fs::path d = work / ("x" + std::to_string(i));
        fs::create_directories(d / "in");
        for (int t = 0; t < 4; ++t) {
            Image f = pattern_frame(40, 24, t);
            for (int k = 0; k < int(rng() % 20); ++k)
                f.pixels[rng() % f.pixels.size()] = extremes[rng() % std::size(extremes)];
            char name[32];
            std::snprintf(name, sizeof name, "f_%04d.exr", t);
            write_image_file((d / "in" / name).string(), f, PixelFormat::ExrFloat, false);
        }
        RunResult r = cli_t("new " + q((d / "in").string()) + " -o " + q((d / "p").string()), 60);
        refused.add(r.code, one_line_naming(r.output, ".exr"), d / "in", r.output);
        r = cli_t(
            "new " + q((d / "in").string()) + " -o " + q((d / "c").string()) + " --nonfinite clean",
            60);
        cleaned.add(r.code, true, d / "in", r.output);
        CHECK(r.code == 0);
    }
    refused.check("extreme pixel values (new)", kPixelClips);
    cleaned.check("extreme pixel values (new --nonfinite clean)", kPixelClips);
    const fs::path c = work / "x0" / "c";
    RunResult r = cli_t("fit " + q(c.string()) + " --iters 4", 120);
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli_t("export " + q(c.string()) + " --what sharp --format exr32 --out " +
              q((work / "x0" / "out").string()));
    REQUIRE(r.code == 0);
    for (const auto& e : fs::directory_iterator(work / "x0" / "out"))
        CHECK(count_nonfinite(read_image_file(e.path().string(), false).image) == 0);
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
    std::mt19937 rng(20261129);
    fuzz_tensor_files(c, work, base, rng);
    fuzz_pixels(work, rng);
}

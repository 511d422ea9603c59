#pragma once
// Minimal argument parsing for the CLI: positionals, "--key value" options and "--flag"s.
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace refocus {

class Args {
  public:
    // `flags` are options that take no value.
    Args(int argc, char** argv, int first, const std::set<std::string>& flags = {}) {
        for (int i = first; i < argc; ++i) {
            std::string a = argv[i];
            if (a.rfind("--", 0) == 0 && a.size() > 2) {
                std::string key = a.substr(2);
                auto eq = key.find('=');
                if (eq != std::string::npos) {
                    add(key.substr(0, eq), key.substr(eq + 1));
                } else if (flags.count(key)) {
                    add(key, "1");
                } else if (i + 1 >= argc) {
                    m_missing = "--" + key;  // reported by check_known, after unknown options
                    m_opts[key] = "";
                } else {
                    add(key, argv[++i]);
                }
            } else if (a == "-o") {
                if (i + 1 >= argc)
                    m_missing = "-o";
                else
                    add("out", argv[++i]);
            } else {
                m_pos.push_back(a);
            }
        }
    }
    const std::vector<std::string>& positional() const { return m_pos; }
    bool has(const std::string& k) const { return m_opts.count(k) > 0; }
    // Every value of an option that may repeat (--set a=1 --set b=2), in order.
    std::vector<std::string> get_all(const std::string& k) const {
        auto it = m_all.find(k);
        return it == m_all.end() ? std::vector<std::string>{} : it->second;
    }
    std::string get(const std::string& k, const std::string& def = "") const {
        auto it = m_opts.find(k);
        return it == m_opts.end() ? def : it->second;
    }
    double get_double(const std::string& k, double def) const {
        if (!has(k)) return def;
        try {
            size_t used = 0;
            double v = std::stod(get(k), &used);
            if (used != get(k).size()) throw std::invalid_argument("");
            return v;
        } catch (const std::exception&) {
            throw std::runtime_error("option --" + k + " needs a number (got '" + get(k) + "')");
        }
    }
    int get_int(const std::string& k, int def) const {
        double v = get_double(k, def);
        if (!(v >= -2147483648.0 && v <= 2147483647.0) || v != static_cast<int>(v))
            throw std::runtime_error("option --" + k + " needs an integer (got '" + get(k) + "')");
        return static_cast<int>(v);
    }
    // Throws on options not in `known` (catches typos such as --frmaes).
    void check_known(const std::set<std::string>& known) const {
        for (const auto& [k, v] : m_opts)
            if (!known.count(k)) throw std::runtime_error("unknown option --" + k);
        if (!m_missing.empty()) throw std::runtime_error("option " + m_missing + " needs a value");
        auto out = m_opts.find("out");
        if (out != m_opts.end() && out->second.empty())
            throw std::runtime_error("option -o/--out needs a path (got an empty one)");
    }

  private:
    void add(const std::string& k, const std::string& v) {
        m_opts[k] = v;  // the last one wins where an option is single
        m_all[k].push_back(v);
    }
    std::vector<std::string> m_pos;
    std::string m_missing;  // the last option, given without its value
    std::map<std::string, std::string> m_opts;
    std::map<std::string, std::vector<std::string>> m_all;
};

}  // namespace refocus

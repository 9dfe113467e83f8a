//! The refinement policy: every rule beyond Fig. 5's link test that decides which links of T a
//! receiver keeps, and how many gather rays each receiver level casts.
//!
//! Fig. 5 keeps a link `T_ij` when `||T_ij|| > epsilon` and, for a finer sender, when it differs
//! from its neighbours' links by more than epsilon. That test is always applied. Each field of
//! [`RefinePolicy`] adds one rule on top of it; [`RefinePolicy::default`] is what every bake
//! uses, and [`RefineRule`] names each rule so that one can be turned off alone (`bake
//! --refine-off RULE`, a diagnostic for ablations: the rule's worth is measured against the path
//! tracer with the rule off).
//!
//! Two observations motivate most rules:
//! - A coarsest receiver has no coarser level to represent what it drops: a dropped link there
//!   is light lost, not a small correction. A link to one of `N` coarse senders is about
//!   `rho / N`, far below epsilon = 0.025 in a closed room of 339 coarse points.
//! - A finer receiver's links are differences from its parents' view (Eq. 17). Each is below
//!   epsilon, but over a wall or near a contact they lean the same way, so dropping them one by
//!   one biases whole surfaces. A budget keeps all but the smallest links whose norms sum to at
//!   most the budget, bounding what the receiver's irradiance can move by.

/// Which links refinement keeps beyond Fig. 5's test, and the gather rays of each level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefinePolicy {
    /// A level-0 receiver keeps every non-zero link to a coarsest sender. Without it a closed
    /// room loses most of its indirect light: level 0 has no coarser level to carry it.
    pub coarsest_block: bool,
    /// A level-0 receiver keeps every non-zero link to finer senders too. They carry the
    /// emission's detail (the pull-push differences: a hot spot, a shadow's edge) to the
    /// receivers that see it from afar; level 0 has no coarser level to represent it.
    pub level0_finer_links: bool,
    /// A level-1 receiver away from contacts keeps its sub-epsilon links to coarsest senders
    /// by a budget of epsilon. At a contact (see `contact_fraction`) a level-1 function
    /// straddles surfaces whose light differs and the budget overshoots between them.
    pub level1_budget: bool,
    /// A level-2 receiver at a contact keeps the same budget: the light a point receives falls
    /// toward the surface it meets, spread over many coarse senders, each below epsilon.
    pub contact_budget: bool,
    /// Levels 2 and 3 keep the same budget (level 3 also at contacts), unless the level is
    /// the file's finest (no finer level would correct its overshoot between points).
    pub middle_budget: bool,
    /// Levels 2 and 3 keep their sub-epsilon links to finer senders by a budget of
    /// `finer_budget_factor` epsilon: the emission's detail as these receivers see it.
    pub finer_budget: bool,
    /// The finer-sender budget in units of epsilon. It is large: each link is a sample of the
    /// emission's detail hit by few rays, so the budget drops the many smallest.
    pub finer_budget_factor: f32,
    /// A finer-sender link the gather hit fewer times than this (but at least once) is not kept
    /// by the budget: it is a one-sample estimate, mostly noise times a near light's large
    /// detail coefficient. Links the gather did not hit are Eq. 17's corrections and stay
    /// candidates. 1 turns the test off.
    pub min_budget_hits: u16,
    /// A receiver with more than this share of its gather hits nearer than its level's disk
    /// radius is at a contact (`level1_budget`, `contact_budget`).
    pub contact_fraction: f32,
    /// Gather rays of a level-0 receiver, in multiples of the bake's `gather_rays`: it keeps
    /// links to small finer senders, whose noise falls with the rays, and level 0 is small.
    pub level0_ray_factor: u32,
    /// Gather rays of a level-1 receiver, in multiples of `gather_rays`: its budget keeps links
    /// near the gather's noise.
    pub level1_ray_factor: u32,
    /// Gather rays of a level-2 or level-3 receiver, in multiples of `gather_rays`: the links
    /// the finer-sender budget keeps rest on few hits each.
    pub middle_ray_factor: u32,
}

impl Default for RefinePolicy {
    fn default() -> Self {
        RefinePolicy {
            coarsest_block: true,
            level0_finer_links: true,
            level1_budget: true,
            contact_budget: true,
            middle_budget: true,
            finer_budget: true,
            finer_budget_factor: 20.0,
            min_budget_hits: 2,
            contact_fraction: 0.05,
            level0_ray_factor: 16,
            level1_ray_factor: 4,
            middle_ray_factor: 4,
        }
    }
}

/// One rule of [`RefinePolicy`], by the name `bake --refine-off` takes.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    clap::ValueEnum,
    serde::Deserialize,
    serde::Serialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum RefineRule {
    CoarsestBlock,
    Level0FinerLinks,
    Level1Budget,
    ContactBudget,
    MiddleBudget,
    FinerBudget,
    MinBudgetHits,
    Level0Rays,
    Level1Rays,
    MiddleRays,
}

impl RefineRule {
    /// Every rule, in the order of [`RefinePolicy`]'s fields.
    pub const ALL: [RefineRule; 10] = [
        RefineRule::CoarsestBlock,
        RefineRule::Level0FinerLinks,
        RefineRule::Level1Budget,
        RefineRule::ContactBudget,
        RefineRule::MiddleBudget,
        RefineRule::FinerBudget,
        RefineRule::MinBudgetHits,
        RefineRule::Level0Rays,
        RefineRule::Level1Rays,
        RefineRule::MiddleRays,
    ];

    /// The rule's command-line name.
    pub fn name(self) -> &'static str {
        match self {
            RefineRule::CoarsestBlock => "coarsest-block",
            RefineRule::Level0FinerLinks => "level0-finer-links",
            RefineRule::Level1Budget => "level1-budget",
            RefineRule::ContactBudget => "contact-budget",
            RefineRule::MiddleBudget => "middle-budget",
            RefineRule::FinerBudget => "finer-budget",
            RefineRule::MinBudgetHits => "min-budget-hits",
            RefineRule::Level0Rays => "level0-rays",
            RefineRule::Level1Rays => "level1-rays",
            RefineRule::MiddleRays => "middle-rays",
        }
    }
}

impl RefinePolicy {
    /// The default policy with `rules` turned off: a budget or keep rule no longer keeps
    /// anything, a ray factor becomes 1, the hit test accepts a single hit.
    pub fn without(rules: &[RefineRule]) -> RefinePolicy {
        let mut p = RefinePolicy::default();
        for rule in rules {
            match rule {
                RefineRule::CoarsestBlock => p.coarsest_block = false,
                RefineRule::Level0FinerLinks => p.level0_finer_links = false,
                RefineRule::Level1Budget => p.level1_budget = false,
                RefineRule::ContactBudget => p.contact_budget = false,
                RefineRule::MiddleBudget => p.middle_budget = false,
                RefineRule::FinerBudget => p.finer_budget = false,
                RefineRule::MinBudgetHits => p.min_budget_hits = 1,
                RefineRule::Level0Rays => p.level0_ray_factor = 1,
                RefineRule::Level1Rays => p.level1_ray_factor = 1,
                RefineRule::MiddleRays => p.middle_ray_factor = 1,
            }
        }
        p
    }

    /// Whether a receiver of `level` keeps its sub-epsilon link of norm > 0 to sender `j`
    /// outright, as the base of the hierarchy: level 0 only (`coarsest_block` for coarsest
    /// senders, `level0_finer_links` for finer ones).
    pub fn keeps_base_link(&self, level: usize, coarsest_sender: bool) -> bool {
        match (level, coarsest_sender) {
            (0, true) => self.coarsest_block,
            (0, false) => self.level0_finer_links,
            _ => false,
        }
    }

    /// Whether a receiver of `level`, in a basis of `levels` levels, keeps its sub-epsilon
    /// links to coarsest senders by a budget of epsilon: level 1 away from contacts, level 2 at
    /// contacts, levels 2 and 3 otherwise unless the level is the finest.
    pub fn keeps_budget(&self, level: usize, contact: bool, levels: usize) -> bool {
        match level {
            1 => !contact && self.level1_budget,
            2 if contact => self.contact_budget,
            2 | 3 => level + 1 < levels && self.middle_budget,
            _ => false,
        }
    }

    /// Whether a receiver of `level` keeps its sub-epsilon links to finer senders by a budget
    /// of [`RefinePolicy::finer_budget_factor`] epsilon: levels 2 and 3.
    pub fn keeps_finer_budget(&self, level: usize) -> bool {
        self.finer_budget && matches!(level, 2 | 3)
    }

    /// Whether a finer-sender link resting on `hits` of the gather's hits may be kept by the
    /// budget ([`RefinePolicy::min_budget_hits`]).
    pub fn budget_sampled(&self, hits: u16) -> bool {
        hits == 0 || hits >= self.min_budget_hits
    }

    /// Whether a receiver whose gather cast `rays` rays, `near` of them hitting nearer than its
    /// level's disk radius, is at a contact.
    pub fn at_contact(&self, near: u64, rays: u64) -> bool {
        near as f32 > self.contact_fraction * rays as f32
    }

    /// The gather rays of a receiver of `level` when the bake asks for `gather_rays`.
    pub fn gather_rays_at(&self, level: usize, gather_rays: u32) -> u32 {
        let factor = match level {
            0 => self.level0_ray_factor,
            1 => self.level1_ray_factor,
            2 | 3 => self.middle_ray_factor,
            _ => 1,
        };
        gather_rays.saturating_mul(factor)
    }

    /// Whether `rule` is in force: its keep rule on, its ray factor or hit test above 1.
    pub fn is_on(&self, rule: RefineRule) -> bool {
        match rule {
            RefineRule::CoarsestBlock => self.coarsest_block,
            RefineRule::Level0FinerLinks => self.level0_finer_links,
            RefineRule::Level1Budget => self.level1_budget,
            RefineRule::ContactBudget => self.contact_budget,
            RefineRule::MiddleBudget => self.middle_budget,
            RefineRule::FinerBudget => self.finer_budget,
            RefineRule::MinBudgetHits => self.min_budget_hits > 1,
            RefineRule::Level0Rays => self.level0_ray_factor > 1,
            RefineRule::Level1Rays => self.level1_ray_factor > 1,
            RefineRule::MiddleRays => self.middle_ray_factor > 1,
        }
    }

    /// The rules that are off, in [`RefineRule::ALL`]'s order (empty for the default).
    pub fn rules_off(&self) -> Vec<RefineRule> {
        RefineRule::ALL
            .into_iter()
            .filter(|&r| !self.is_on(r))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_rule_turns_off_one_field_and_is_named_back() {
        let d = RefinePolicy::default();
        assert!(d.rules_off().is_empty());
        for rule in RefineRule::ALL {
            let p = RefinePolicy::without(&[rule]);
            assert_ne!(p, d, "{} changes nothing", rule.name());
            assert_eq!(p.rules_off(), vec![rule], "{}", rule.name());
            let value = clap::ValueEnum::to_possible_value(&rule).expect("named");
            assert_eq!(value.get_name(), rule.name());
        }
        let two = RefinePolicy::without(&[RefineRule::MiddleRays, RefineRule::CoarsestBlock]);
        assert_eq!(
            two.rules_off(),
            vec![RefineRule::CoarsestBlock, RefineRule::MiddleRays]
        );
    }

    #[test]
    fn default_budgets_follow_level_and_contact() {
        let p = RefinePolicy::default();
        // Level 1 away from contacts only; levels 2 and 3 at and away from contacts, but not
        // away from contacts at the finest level (level 2 at a contact keeps it even there);
        // nothing at 0 or 4+.
        assert!(p.keeps_budget(1, false, 6) && !p.keeps_budget(1, true, 6));
        assert!(p.keeps_budget(2, true, 3) && p.keeps_budget(2, false, 6));
        assert!(!p.keeps_budget(2, false, 3) && !p.keeps_budget(3, false, 4));
        assert!(p.keeps_budget(3, false, 5) && p.keeps_budget(3, true, 6));
        assert!(!p.keeps_budget(0, false, 6) && !p.keeps_budget(4, false, 6));
        assert!(p.keeps_finer_budget(2) && p.keeps_finer_budget(3));
        assert!(!p.keeps_finer_budget(1) && !p.keeps_finer_budget(4));
        let off = RefinePolicy::without(&[RefineRule::ContactBudget]);
        assert!(!off.keeps_budget(2, true, 6) && off.keeps_budget(2, false, 6));
        // One hit is not enough by default, none or two are.
        assert!(p.budget_sampled(0) && !p.budget_sampled(1) && p.budget_sampled(2));
        assert!(RefinePolicy::without(&[RefineRule::MinBudgetHits]).budget_sampled(1));
    }

    #[test]
    fn ray_factors_multiply_the_bakes_rays_per_level() {
        let p = RefinePolicy::default();
        let rays: Vec<u32> = (0..6).map(|l| p.gather_rays_at(l, 64)).collect();
        assert_eq!(rays, [1024, 256, 256, 256, 64, 64]);
        let flat = RefinePolicy::without(&[
            RefineRule::Level0Rays,
            RefineRule::Level1Rays,
            RefineRule::MiddleRays,
        ]);
        assert!((0..6).all(|l| flat.gather_rays_at(l, 64) == 64));
        assert_eq!(p.gather_rays_at(0, u32::MAX), u32::MAX);
    }

    #[test]
    fn base_links_are_level_0_links() {
        let p = RefinePolicy::default();
        assert!(p.keeps_base_link(0, true) && p.keeps_base_link(0, false));
        assert!((1..6).all(|l| !p.keeps_base_link(l, true) && !p.keeps_base_link(l, false)));
        let off = RefinePolicy::without(&[RefineRule::Level0FinerLinks]);
        assert!(off.keeps_base_link(0, true) && !off.keeps_base_link(0, false));
        let off = RefinePolicy::without(&[RefineRule::CoarsestBlock]);
        assert!(!off.keeps_base_link(0, true) && off.keeps_base_link(0, false));
    }
}
